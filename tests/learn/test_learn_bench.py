"""The learned-simulator benchmark runs end to end on a small mesh (figures only, no timing assertions)."""

from __future__ import annotations

import pytest

from thrsim.data.synthetic import block_mesh
from thrsim.learn.bench import _four_times_area, time_production, time_thesis_way, untrained_model
from thrsim.learn.settings import preset


def test_benchmark_figures_come_out_for_both_configurations():
    mesh = block_mesh(n=4)
    production = time_production(untrained_model(mesh, preset("production"), teeth_radius_m=3e-3), frames=2, inclination_deg=0.0)
    assert production["elements"] == mesh.n_tets and production["frames"] == 2
    assert production["ms_per_frame_median"] > 0 and 0 < production["region_elements_median"] <= mesh.n_tets
    thesis = time_thesis_way(mesh, frames=1, teeth_radius_m=3e-3, inclination_deg=0.0)
    assert thesis["ms_per_frame_median"] >= thesis["network_ms_median"] > 0


def test_four_times_the_area_of_a_spherical_cap():
    import numpy as np

    half = _four_times_area(19.0)
    assert np.isclose(1 - np.cos(np.radians(half)), 4 * (1 - np.cos(np.radians(19.0))))


def test_the_socket_model_s_step_is_timed_on_the_whole_socket():
    from thrsim.learn.bench import time_socket_steps

    (row,) = time_socket_steps(None, frames=2, element_sizes_mm=(2.5,))
    assert row["element_size_mm"] == 2.5 and row["elements"] > 1000 and row["weights"] == "initial"
    assert row["step_ms_median"] > 0 and row["step_ms_max"] >= row["step_ms_median"]
    assert row["region_elements_max"] > 0  # the reamer reached the articular face


def test_the_socket_model_is_timed_pushed_with_its_reamers_one_after_another(tiny_socket_model):
    from thrsim.learn.bench import SOCKET_BENCH_REAMERS_MM, time_socket_steps
    from thrsim.learn.model_dir import load_model

    model = load_model(tiny_socket_model)
    (row,) = time_socket_steps(model, frames=3, element_sizes_mm=(2.5,), compile=True)
    assert row["weights"] == "trained"
    for pushed in (row["pushed"], row["pushed_compiled"]):
        assert pushed["reamers_mm"] == list(SOCKET_BENCH_REAMERS_MM)
        assert (
            pushed["frames"] == 3 * len(SOCKET_BENCH_REAMERS_MM)
            and pushed["step_ms_max"] >= pushed["step_ms_p99"] >= pushed["step_ms_median"] > 0
        )
        assert pushed["depth_mm"] >= 0.0 and pushed["removed_volume_mm3"] >= 0.0
    # the same chain reams the same bone, compiled or not, and the caller's model stays eager
    assert row["pushed_compiled"]["removed_volume_mm3"] == pytest.approx(row["pushed"]["removed_volume_mm3"], rel=0.05)
    assert row["pushed_compiled"]["network"] in ("compiled", "eager") and not getattr(model.gn, "network_compiled", False)
