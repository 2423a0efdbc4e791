"""``thrsim bench --browser-only`` runs end to end in a real headless Chromium (figures only, no
timing assertions: speed targets live in ``thrsim bench``, never in tests)."""

from __future__ import annotations

import json
import shutil

import pytest
from checkout_cli import run_thrsim

from thrsim.app.drawing_bench import CHROMIUM

pytestmark = pytest.mark.skipif(shutil.which(CHROMIUM) is None, reason="Debian chromium is not installed (./install.sh installs it)")


def test_browser_benchmark_counts_the_frames_the_page_draws():
    completed = run_thrsim("bench", "--browser-only", "--browser-seconds", "2", timeout=240)
    assert completed.returncode == 0, completed.stderr[-3000:]
    figures = json.loads(completed.stdout)["browser"]
    assert figures["frames"] > 0 and figures["fps"] == pytest.approx(figures["frames"] / figures["seconds"])
    assert figures["seconds"] >= 2 and figures["page_states_per_s"] > 0
    assert "SwiftShader" in figures["webgl_renderer"] and figures["canvas"] == [1280, 720]
    assert figures["draw_calls"] > 0 and figures["triangles"] > 0


def test_browser_only_refuses_learned():
    completed = run_thrsim("bench", "--browser-only", "--learned")
    assert completed.returncode == 2 and "--learned" in completed.stderr
