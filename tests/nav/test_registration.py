"""Landmark registration: 27 targets acquired by a simulated trainee through the tracking model,
with noise, dwell, a tracking loss, the rigid fit residual and the APP from acquired points."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from thrsim.config import TrackingVolumeConfig
from thrsim.errors import ThrsimInputError
from thrsim.nav import PROBE, REFERENCE_FRAME, LandmarkRegistration, Sphere, TrackingCamera, angles_in_frame, synthetic_pelvis_landmarks
from thrsim.nav.registration import RegistrationEvent
from thrsim.nav.rigid import invert, make_pose, transform_points
from thrsim.nav.tracking import Visibility

pytestmark = pytest.mark.timeout(60)

FACING = Rotation.from_euler("x", 180.0, degrees=True)  # mount normal toward a camera at the origin
REFERENCE_FROM_MODEL = make_pose(Rotation.from_euler("xyz", [8.0, -5.0, 30.0], degrees=True), [0.02, 0.12, -0.04])
_WORLD_ROTATION = (FACING * Rotation.from_euler("z", 20.0, degrees=True)).as_matrix()
# Centre the pelvis a little above the camera axis: the probe's markers sit 0.15 m below its tip.
WORLD_FROM_REFERENCE = make_pose(_WORLD_ROTATION, np.array([0.0, 0.08, 1.5]) - _WORLD_ROTATION @ REFERENCE_FROM_MODEL[:3, 3])
MOVE_S, HOLD_S = 0.3, 0.7
TRACKED = Visibility(True, "tracked", 0.0, 4)


def simulate(side: str, occlude_between: tuple[float, float] | None = None):
    model = synthetic_pelvis_landmarks(side)
    targets = {name: transform_points(REFERENCE_FROM_MODEL, p[None])[0] for name, p in model.items()}
    registration = LandmarkRegistration(targets)
    camera = TrackingCamera(seed=3)
    names = list(targets)
    world_targets = {n: transform_points(WORLD_FROM_REFERENCE, p[None])[0] for n, p in targets.items()}

    def probe_pose(t: float) -> np.ndarray:
        index = min(int(t // (MOVE_S + HOLD_S)), len(names) - 1)
        phase = t - index * (MOVE_S + HOLD_S)
        start = world_targets[names[index - 1]] if index else world_targets[names[0]] + [0.0, 0.05, 0.0]
        tip = start + min(phase / MOVE_S, 1.0) * (world_targets[names[index]] - start)
        rotation = FACING.as_matrix()
        return make_pose(rotation, tip - rotation @ PROBE.tip)

    events: list[RegistrationEvent] = []
    for k in range(int(len(names) * (MOVE_S + HOLD_S) * 60) + 30):
        t = k / 60.0
        occluders = []
        if occlude_between and occlude_between[0] <= t < occlude_between[1]:
            probe_origin = probe_pose(t)[:3, 3]
            occluders = [Sphere(0.5 * probe_origin, 0.03)]
        probe_visibility = camera.observe(PROBE, probe_pose(t), occluders)
        reference_visibility = camera.observe(REFERENCE_FRAME, WORLD_FROM_REFERENCE, occluders)
        tip = None
        if probe_visibility.tracked and reference_visibility.tracked:
            probe_measured = camera.measure(PROBE, probe_pose(t))
            reference_measured = camera.measure(REFERENCE_FRAME, WORLD_FROM_REFERENCE)
            tip = transform_points(invert(reference_measured) @ probe_measured, PROBE.tip[None])[0]
        events += registration.update(t, tip, probe_visibility, reference_visibility)
    return registration, model, events


@pytest.mark.parametrize("side", ["right", "left"])
def test_full_workflow_acquires_27_landmarks_with_sub_millimetre_residual(side):
    registration, model, events = simulate(side, occlude_between=(2.1, 2.4))
    kinds = [e.kind for e in events]
    assert registration.done and len(registration.acquired) == 27
    assert kinds.count("acquired") == 27 and kinds.count("target") == 27 and kinds[-1] == "completed"
    lost = [e for e in events if e.kind == "tracking_lost"]
    assert len(lost) == 1 and "probe occluded" in lost[0].detail and "tracking_regained" in kinds
    assert max(e.error_m for e in events if e.kind == "acquired") < 1e-3

    result = registration.result(model, side=side)
    assert result.rms_residual_m < 1e-3
    assert result.fit.pose[:3, 3] == pytest.approx(REFERENCE_FROM_MODEL[:3, 3], abs=1e-3)
    rotation_error = Rotation.from_matrix(result.fit.pose[:3, :3] @ REFERENCE_FROM_MODEL[:3, :3].T).magnitude()
    assert np.degrees(rotation_error) < 0.5

    # A cup axis at radiographic 40/15 in the model pelvis reads 40/15 in the registered APP.
    lateral = [1.0 if side == "right" else -1.0, 0.0, 0.0]
    ri, ra = np.radians(40.0), np.radians(15.0)
    axis_model = (
        np.cos(ra) * np.sin(ri) * np.array(lateral) + np.sin(ra) * np.array([0, 1.0, 0]) + np.cos(ra) * np.cos(ri) * np.array([0, 0, -1.0])
    )
    axis_reference = REFERENCE_FROM_MODEL[:3, :3] @ axis_model
    assert angles_in_frame(axis_reference, result.app) == pytest.approx((40.0, 15.0), abs=0.5)


def test_dwell_requires_holding_still_within_tolerance():
    config = TrackingVolumeConfig()
    registration = LandmarkRegistration({"a": [0, 0, 0], "b": [0.1, 0, 0], "c": [0, 0.1, 0]}, config)
    events = registration.update(0.0, np.array([0.01, 0, 0]), TRACKED, TRACKED)  # 10 mm off: too far
    assert [e.kind for e in events] == ["target"]
    for k in range(60):  # on target (< 5 mm) but wandering ±3.5 mm: never settles
        assert not registration.update(k / 60, np.array([0.0, 0.0035 * (-1) ** k, 0.0]), TRACKED, TRACKED)
    acquired = []
    for k in range(60):
        acquired += [e for e in registration.update(1 + k / 60, np.array([0.001, 0, 0]), TRACKED, TRACKED) if e.kind == "acquired"]
    assert len(acquired) == 1 and acquired[0].landmark == "a"
    assert acquired[0].time_s == pytest.approx(1 + config.dwell_s, abs=1 / 60)
    assert registration.current_target == "b"


def test_lost_tracking_names_tool_and_reason_once():
    registration = LandmarkRegistration({"a": [0, 0, 0], "b": [0.1, 0, 0], "c": [0, 0.1, 0]})
    angle = Visibility(False, "angle", 60.0, 4)
    outside = Visibility(False, "outside_volume", 0.0, 2)
    first = registration.update(0.0, None, angle, outside)
    assert [e.kind for e in first] == ["target", "tracking_lost"]
    assert first[1].detail == "probe angle, reference outside_volume"
    assert registration.update(0.1, None, angle, outside) == []
    assert [e.kind for e in registration.update(0.2, np.zeros(3), TRACKED, TRACKED)] == ["tracking_regained"]


def test_result_before_completion_and_bad_targets_are_refused():
    registration = LandmarkRegistration({"a": [0, 0, 0], "b": [0.1, 0, 0], "c": [0, 0.1, 0]})
    with pytest.raises(ThrsimInputError, match="incomplete: 0 of 3"):
        registration.result({})
    with pytest.raises(ThrsimInputError, match="at least 3"):
        LandmarkRegistration({"a": [0, 0, 0]})
    with pytest.raises(ThrsimInputError, match="finite 3-vector"):
        LandmarkRegistration({"a": [0, 0, np.nan], "b": [0.1, 0, 0], "c": [0, 0.1, 0]})
