"""``thrsim bench`` reports the solver's cost per active element and step (figures only; no timing is asserted)."""

from __future__ import annotations

import json

from checkout_cli import run_thrsim


def test_bench_reports_cost_per_active_element():
    done = run_thrsim("bench", "--frames", "1", "--element-size", "1.6", timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    solver = json.loads(done.stdout)["solver"]
    # the patch integrates every element still there
    assert 0.5 * solver["elements"] < solver["active_elements_median"] <= solver["elements"]
    assert solver["ns_per_active_element_step"] > 0 and solver["frames_timed"] == 1
    per_step_ns = solver["ns_per_active_element_step"] * solver["active_elements_median"]
    assert abs(solver["ms_per_step"] * 1e6 / per_step_ns - 1) < 1e-9


def test_bench_socket_is_not_a_page_figure():
    done = run_thrsim("bench", "--browser-only", "--socket")
    assert done.returncode == 2 and "--socket" in done.stderr
