"""NaN, infinity, out-of-range and oversized values in configuration files are refused through the
real command: one line on stderr, exit 2, nothing written, never a traceback (issue 27, item 6)."""

from __future__ import annotations

import pytest
from test_cli_errors import assert_one_line_error

BAD_CASE_SETTINGS = {
    "nan_spin": ('{"reamer": {"omega_rad_s": NaN}}', "reamer.omega_rad_s: Input should be a finite number"),
    "nan_damage_d1": ('{"damage": {"d1": NaN}}', "damage.d1: Input should be a finite number"),
    "infinite_force": ('{"force_n": Infinity}', "force_n: Input should be a finite number"),
    "tiny_frame_rate": ('{"frame_rate_hz": 1e-300}', "frame_rate_hz"),
    "huge_frame_rate": ('{"frame_rate_hz": 1e9}', "frame_rate_hz"),
    "tiny_time_step": ('{"solver": {"target_dt_s": 1e-300}}', "target_dt_s"),
    "too_many_frames": ('{"frames": 1000000000000}', "frames"),
    "integer_of_5000_digits": ('{"frames": ' + "9" * 5000 + "}", "not valid JSON"),
    "json_100k_deep": ('{"a": ' * 100_000 + "1" + "}" * 100_000, "nested too deeply"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASE_SETTINGS))
def test_fem_refuses_a_bad_configuration_file(thrsim_inprocess, tmp_path, case):
    text, needle = BAD_CASE_SETTINGS[case]
    (tmp_path / "case.json").write_text(text)
    args = ("fem", "--inclination", "15", "--anteversion", "30", "--config", "case.json", "--out", "c.h5", "--json")
    assert_one_line_error(thrsim_inprocess(*args, cwd=tmp_path), needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case.json"]


@pytest.mark.parametrize(
    ("text", "needle"),
    [('{"train": {"learning_rate": NaN}}', "train.learning_rate"), ('{"train": {"gradient_clip": Infinity}}', "train.gradient_clip")],
)
def test_train_refuses_non_finite_settings(thrsim_inprocess, tmp_path, text, needle):
    (tmp_path / "settings.json").write_text(text)
    (tmp_path / "data").mkdir()
    args = ("train", "--data", "data", "--out", "model", "--settings", "settings.json")
    assert_one_line_error(thrsim_inprocess(*args, cwd=tmp_path), needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "settings.json"]


def test_dataset_refuses_a_deeply_nested_configuration(thrsim_inprocess, tmp_path):
    (tmp_path / "sweep.json").write_text("[" * 100_000 + "]" * 100_000)
    args = ("dataset", "--out", "data", "--solver", "synthetic", "--config", "sweep.json", "--json")
    assert_one_line_error(thrsim_inprocess(*args, cwd=tmp_path), "nested too deeply")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sweep.json"]


HUGE = "9" * 23  # beyond a C long long: PyTorch's thread count overflowed
FEM = ("fem", "--inclination", "15", "--anteversion", "30", "--out", "c.h5")
BAD_FLAGS = {
    "fem_force_nan": ((*FEM, "--force", "nan"), "force_n (--force): Input should be a finite number"),
    "fem_inclination_nan": (("fem", "--inclination", "nan", "--anteversion", "30", "--out", "c.h5"), "--inclination must lie in"),
    "ream_force_nan": (("ream", "--force", "nan", "--out", "r"), "force must be finite"),
    "ream_force_1e300": (("ream", "--force", "1e300", "--out", "r"), "force must be finite, non-negative and at most 10000 N"),
    "ream_threads_huge": (("ream", "--threads", HUGE, "--out", "r"), "--threads must lie in 1..4096"),
    "train_threads_huge": (("train", "--data", "data", "--out", "model", "--threads", HUGE), "--threads must lie in 1..4096"),
    "evaluate_threads_huge": (("evaluate", "--data", "data", "--threads", HUGE), "--threads must lie in 1..4096"),
    "dataset_connect_timeout_nan": (("dataset", "--out", "d", "--dry-run", "--connect-timeout", "nan"), "--connect-timeout"),
    "mesh_thickness_1e300": (("mesh", "--out", "m.vtu", "--thickness", "1e300"), "thickness_mm: Input should be less than or equal to 50"),
    "mesh_half_angle_1e-300": (("mesh", "--out", "m.vtu", "--half-angle", "1e-300"), "gmsh cannot build"),
    "track_duration_nan": (("track", "--igtl-port", "0", "--duration", "nan"), "--duration must be positive"),
    "track_log_interval_nan": (("track", "--igtl-port", "0", "--log-interval", "nan"), "--log-interval"),
    "serve_seed_negative": (("serve", "--port", "0", "--igtl-port", "0", "--seed", "-1"), "--seed must be a non-negative integer"),
    "serve_side_unknown": (("serve", "--port", "0", "--igtl-port", "0", "--side", "middle"), "--side"),  # made sessions/ first
    "serve_igtl_allow_bogus": (("serve", "--port", "0", "--igtl-port", "0", "--igtl-allow", "bogus"), "--igtl-allow"),
    "serve_haptic_hz_nan": (
        ("serve", "--port", "0", "--igtl-port", "0", "--haptic-port", "0", "--haptic-hz", "nan"),
        "--haptic-hz: must lie in",
    ),
    "serve_haptic_hz_low": (
        ("serve", "--port", "0", "--igtl-port", "0", "--haptic-port", "0", "--haptic-hz", "50"),
        "--haptic-hz: must lie in",
    ),
    "serve_haptic_port_huge": (
        ("serve", "--port", "0", "--igtl-port", "0", "--haptic-port", "70000"),
        "--haptic-port: must lie in 0..65535",
    ),
    "serve_socket_element_size_inf": (
        ("serve", "--port", "0", "--igtl-port", "0", "--socket-element-size", "inf"),
        "--socket-element-size: must lie in",
    ),
    "serve_phantom_missing": (("serve", "--port", "0", "--igtl-port", "0", "--phantom", "none.json"), "cannot read the phantom file"),
    "fem_threads_huge": ((*FEM, "--threads", HUGE), "solver.threads (--threads): Input should be less than or equal to 4096"),  # ran
    "fem_effective_mass_1e300": ((*FEM, "--effective-mass", "1e300"), "--effective-mass"),
    "fem_reamer_diameter_inf": ((*FEM, "--reamer-diameter", "inf"), "head_diameter_mm"),  # OverflowError: traceback
    "ream_frames_huge": (("ream", "--frames", HUGE, "--out", "r"), "--frames: Input should be less than or equal to 100000"),  # ran
    "dataset_workers_huge": (("dataset", "--out", "d", "--dry-run", "--workers", HUGE), "--workers must lie in 1..4096"),
}


@pytest.mark.parametrize("case", sorted(BAD_FLAGS))
def test_a_bad_number_on_the_command_line_is_one_line(thrsim_inprocess, tmp_path, case):
    """NaN, overflowing or impossible numbers in flags, each refused before any work (issue 27, item 5):
    these ran with exit 0 (force 1e300), hung (a NaN duration) or ended in a traceback (a thread count
    of 23 digits, a seed of -1, a shell gmsh cannot build)."""
    args, needle = BAD_FLAGS[case]
    (tmp_path / "data").mkdir()
    assert_one_line_error(thrsim_inprocess(*args, cwd=tmp_path), needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]
