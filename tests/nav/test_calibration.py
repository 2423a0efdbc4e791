"""Frame calibration tracker → headset: robust averaging, residuals, refusals."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from thrsim.errors import ThrsimInputError
from thrsim.nav import CalibrationRefused, calibrate_frames
from thrsim.nav.rigid import invert, make_pose

pytestmark = pytest.mark.timeout(30)

HEAD_FROM_TRACKER = make_pose(Rotation.from_euler("zyx", [90.0, 10.0, -5.0], degrees=True), [0.4, -0.2, 1.1])


def recording(count: int, rotation_noise_deg: float, translation_noise_m: float, glitch_fraction: float = 0.0, seed: int = 0):
    rng = np.random.default_rng(seed)
    head, tracker = [], []
    for _ in range(count):
        target = make_pose(Rotation.from_euler("zyx", rng.uniform(-30, 30, 3), degrees=True), rng.uniform(-0.3, 0.3, 3) + [0, 0, 1.5])
        noise = make_pose(
            Rotation.from_rotvec(rng.normal(0, np.radians(rotation_noise_deg) / np.sqrt(3), 3)),
            rng.normal(0, translation_noise_m / np.sqrt(3), 3),
        )
        if rng.random() < glitch_fraction:  # a headset tracking glitch: a pose far off
            noise = make_pose(Rotation.from_rotvec(rng.normal(0, 0.3, 3)), rng.normal(0, 0.1, 3))
        tracker.append(target)
        head.append(noise @ HEAD_FROM_TRACKER @ target)
    return np.array(head), np.array(tracker)


def errors(transform):
    rotation = np.degrees(Rotation.from_matrix(transform[:3, :3] @ HEAD_FROM_TRACKER[:3, :3].T).magnitude())
    return rotation, np.linalg.norm(transform[:3, 3] - HEAD_FROM_TRACKER[:3, 3])


def test_exact_samples_recover_the_transform():
    head, tracker = recording(12, 0.0, 0.0)
    result = calibrate_frames(head, tracker)
    assert result.transform == pytest.approx(HEAD_FROM_TRACKER, abs=1e-9)
    assert result.used == 12 and result.rejected == 0


def test_noisy_average_and_glitches_gated():
    head, tracker = recording(60, 1.0, 0.003, glitch_fraction=0.1, seed=4)
    result = calibrate_frames(head, tracker)
    rotation_error, translation_error = errors(result.transform)
    assert rotation_error < 0.5 and translation_error < 0.006
    assert result.rejected >= 3 and result.used >= 50
    assert 0.3 < result.rotation_residual_rms_deg < 2.0
    # Without the gate (plain mean) the glitches dominate: the gate is what helps.
    plain = Rotation.from_matrix((head @ np.array([invert(t) for t in tracker]))[:, :3, :3]).mean()
    plain_error = np.degrees((plain * Rotation.from_matrix(HEAD_FROM_TRACKER[:3, :3]).inv()).magnitude())
    assert plain_error > rotation_error


def test_refuses_too_few_samples():
    head, tracker = recording(5, 1.0, 0.003)
    with pytest.raises(CalibrationRefused, match="too few samples: 5 < 10"):
        calibrate_frames(head, tracker)


def test_refuses_inconsistent_samples():
    head, tracker = recording(40, 1.0, 0.003)
    rng = np.random.default_rng(9)
    head = np.array([make_pose(Rotation.random(random_state=rng), rng.uniform(-1, 1, 3)) for _ in range(40)])
    with pytest.raises(CalibrationRefused, match="too inconsistent"):
        calibrate_frames(head, tracker)


def test_refuses_when_residual_exceeds_limit():
    head, tracker = recording(40, 8.0, 0.003, seed=2)
    with pytest.raises(CalibrationRefused, match="rotation residual"):
        calibrate_frames(head, tracker)


def test_bad_poses_and_shapes_are_input_errors():
    head, tracker = recording(12, 0.0, 0.0)
    head[3, 0, 0] = np.nan
    with pytest.raises(ThrsimInputError, match="headset pose 3 contains NaN"):
        calibrate_frames(head, tracker)
    with pytest.raises(ThrsimInputError, match="equal length"):
        calibrate_frames(head[:5], tracker)
