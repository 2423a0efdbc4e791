"""``thrsim bench --browser-only`` runs end to end in a real headless Chromium (figures only, no
timing assertions: speed targets live in ``thrsim bench``, never in tests)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
from checkout_cli import run_thrsim

import thrsim.app
from thrsim.app.drawing_bench import CHROMIUM

# The page's render scales (thrsim/app/static/render_scale.js: `export const STEPS = [...]`).
_SOURCE = (Path(thrsim.app.__file__).parent / "static" / "render_scale.js").read_text()
RENDER_SCALE_STEPS = json.loads(re.search(r"export const STEPS = (\[[^\]]*\])", _SOURCE).group(1))

pytestmark = pytest.mark.skipif(shutil.which(CHROMIUM) is None, reason="Debian chromium is not installed (./install.sh installs it)")


def test_browser_benchmark_counts_the_frames_the_page_draws():
    completed = run_thrsim("bench", "--browser-only", "--browser-seconds", "2", timeout=240)
    assert completed.returncode == 0, completed.stderr[-3000:]
    figures = json.loads(completed.stdout)["browser"]
    assert figures["frames"] > 0 and figures["fps"] == pytest.approx(figures["frames"] / figures["seconds"])
    assert figures["seconds"] >= 2 and figures["page_states_per_s"] > 0
    assert "SwiftShader" in figures["webgl_renderer"] and figures["viewport"] == [1280, 720]
    # The canvas is drawn at the render scale the page ended at (lowered while frames are slow).
    scale = figures["render_scale"]
    assert scale in RENDER_SCALE_STEPS and figures["render_scale_at_start"] in RENDER_SCALE_STEPS
    assert figures["canvas"] == [int(1280 * scale), int(720 * scale)] and figures["render_scale_changes"] >= 0
    assert figures["draw_calls"] > 0 and figures["triangles"] > 0


def test_browser_only_refuses_learned():
    completed = run_thrsim("bench", "--browser-only", "--learned")
    assert completed.returncode == 2 and "--learned" in completed.stderr
