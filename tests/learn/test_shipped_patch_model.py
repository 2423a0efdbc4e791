"""The shipped patch model: the physics its autonomous feed must obey, on the simulator and in ``evaluate``'s checks."""

from __future__ import annotations

import numpy as np
import pytest
from learn_helpers import REPO

from thrsim.learn.cases import load_cases
from thrsim.learn.evaluation import physics_checks
from thrsim.learn.model_dir import SHIPPED_MODEL, load_model
from thrsim.learn.simulator import ReamingSimulator

# off the training grid: γ 22.5°, θ 100°
AXIS = np.array(
    [np.sin(np.radians(22.5)) * np.cos(np.radians(100)), np.sin(np.radians(22.5)) * np.sin(np.radians(100)), -np.cos(np.radians(22.5))]
)


@pytest.fixture(scope="module")
def model():
    return load_model(SHIPPED_MODEL)


def _ream(model, force_n: float, frames: int = 30) -> tuple[float, float]:
    simulator = ReamingSimulator(model=model)
    results = [simulator.step(AXIS, force_n) for _ in range(frames)]
    return results[-1].removed_volume_m3, float(sum(r.advance_m for r in results))


def test_no_push_no_cut_and_more_push_never_less(model):
    assert _ream(model, 0.0) == (0.0, 0.0)
    reamed = [_ream(model, force) for force in (100.0, 150.0, 230.0, 310.0)]
    volumes, depths = zip(*reamed, strict=True)
    assert list(volumes) == sorted(volumes) and list(depths) == sorted(depths) and volumes[0] > 0.0


def test_evaluates_physics_checks_hold_on_a_held_out_case(model):
    _, cases = load_cases(REPO / "datasets" / "default-0.4.0", splits=("test",), one_mesh=False)
    checks = physics_checks(model, cases[:1], frames=20)
    assert checks["held"] == {"no_push_no_cut": 1, "no_push_no_advance": 1, "more_push_never_less": 1}
    by_share = checks["removed_volume_mm3_mean_by_push_share"]
    assert by_share["0"] == 0.0 and by_share["0.5"] > 0.0


def test_a_push_or_a_reamer_the_patch_model_did_not_learn_is_flagged(model):
    simulator = ReamingSimulator(model=model)
    low, high = model.trained_force_n
    assert simulator.step(AXIS, 0.5 * (low + high)).out_of_range == ()
    assert "push" in simulator.step(AXIS, 0.5 * low).out_of_range
    assert "reamer size" in simulator.step(AXIS, 0.5 * (low + high), reamer_mm=model.trained_reamer_mm[0] + 4.0).out_of_range


def test_a_tilt_direction_beyond_the_half_circle_it_learned_feeds_as_its_mirror_image(model):
    """θ 330° reads the regressor at 30°: the shipped SVR, read at 330° itself, ran a 230 N reamer
    through the 2 mm patch in 10 frames (13 mm/s; the solver takes about 1.6 s)."""
    assert model.trained_anteversion_deg == (0.0, 180.0)

    def tilted(theta_deg: float) -> np.ndarray:
        gamma, theta = np.radians(7.0), np.radians(theta_deg)
        return np.array([np.sin(gamma) * np.cos(theta), np.sin(gamma) * np.sin(theta), -np.cos(gamma)])

    advances = {}
    for theta_deg in (30.0, 330.0):
        simulator = ReamingSimulator(model=model)
        advances[theta_deg] = [simulator.step(tilted(theta_deg), 230.0).advance_m for _ in range(10)]
    assert advances[330.0] == pytest.approx(advances[30.0], rel=1e-2)
    assert 1e3 * sum(advances[330.0]) / (10 / 60) < 5.0  # mm/s: far below a runaway
