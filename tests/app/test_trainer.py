"""The navigation trainer's logic with real thrsim.nav numerics: registration, visibility,
angles against the safe zone, display calibration, tracker poses, refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from app_helpers import reamer_to_reference

from thrsim.app.controls import parse_control
from thrsim.app.navigation import CALIBRATION_SAMPLES, NavigationTrainer
from thrsim.errors import ThrsimInputError
from thrsim.nav.anatomy import angles_in_frame
from thrsim.nav.rigid import invert, transform_points
from thrsim.nav.tracking import PROBE

STEP = 1 / 60


class Clock:
    def __init__(self, trainer: NavigationTrainer):
        self.trainer, self.now, self.state = trainer, 0.0, None

    def run(self, seconds: float) -> dict:
        for _ in range(int(round(seconds / STEP))):
            self.now += STEP
            self.state = self.trainer.step(self.now)
        return self.state

    def control(self, message: dict) -> str:
        return self.trainer.apply_control(parse_control(message), self.now)


def register_all(clock: Clock) -> list[dict]:
    events = []
    for _ in range(40):
        if clock.trainer.registration.done:
            break
        clock.control({"type": "probe", "action": "touch"})
        for _ in range(45):
            events += clock.run(STEP)["events"]
    return events


def test_registration_builds_the_app_close_to_the_true_one():
    clock = Clock(NavigationTrainer(seed=1))
    clock.run(0.1)
    assert clock.state["app_source"] == "model"
    events = register_all(clock)
    state = clock.run(STEP)
    assert state["registration"]["done"] and len(state["registration"]["acquired"]) == 27
    assert [e["kind"] for e in events].count("acquired") == 27
    assert "completed" in [e["kind"] for e in events] and state["app_source"] == "registered"
    # Hand error of ~2 mm gives a fit residual of the same order and an APP within a degree or two.
    assert 0.3 < state["registration"]["rms_mm"] < 5.0
    trainer = clock.trainer
    axis = trainer.tools["Reamer"].pose[:3, :3] @ np.array([0.0, 0.0, 1.0])
    true = angles_in_frame(axis, trainer.true_app)
    measured = state["angles"]["radiographic"]
    assert abs(measured[0] - true[0]) < 3.0 and abs(measured[1] - true[1]) < 3.0
    assert (true[0], true[1]) == pytest.approx((60.0, 10.0), abs=1e-6)  # the page steers in the true APP


def test_every_touch_from_the_page_lands_within_the_acquisition_tolerance():
    """The hand's offset is random (mm scale) but a touch never misses: the page has no other way
    to place the probe, so one outside the tolerance would stall registration for good."""
    trainer = NavigationTrainer(seed=3)
    clock = Clock(trainer)
    target = trainer.registration.current_target
    tolerance_m = trainer.tracking.landmark_tolerance_mm * 1e-3
    distances = []
    for _ in range(3000):
        clock.control({"type": "probe", "action": "touch"})
        tip = transform_points(trainer.tools["Probe"].pose, PROBE.tip[None])[0]
        distances.append(np.linalg.norm(tip - trainer.targets[target]))
    distances = np.array(distances)
    assert distances.max() < 0.8 * tolerance_m  # the offset plus a tremor sample
    assert 1.0e-3 < np.median(distances) < 2.5e-3  # still a hand, not a perfect pointer


def test_safe_zone_colour_follows_the_steered_reamer():
    clock = Clock(NavigationTrainer(seed=2))
    colours = {}
    for inclination, anteversion in ((40, 15), (53, 15), (70, 40)):
        clock.control({"type": "reamer", "inclination_deg": inclination, "anteversion_deg": anteversion})
        colours[(inclination, anteversion)] = clock.run(STEP)["zone"]["colour"]
    assert colours == {(40, 15): "green", (53, 15): "amber", (70, 40): "red"}


def test_camera_turned_away_loses_tools_by_angle_and_far_camera_by_volume():
    clock = Clock(NavigationTrainer(seed=3))
    clock.control({"type": "probe", "action": "touch"})
    assert {t["reason"] for t in clock.run(STEP)["tools"].values()} == {"tracked"}
    clock.control({"type": "camera", "azimuth_deg": -130, "elevation_deg": 10, "distance_mm": 1600})
    state = clock.run(STEP)
    assert state["tools"]["Reference"]["reason"] == "angle" and state["angles"] is None
    clock.control({"type": "camera", "azimuth_deg": 50, "elevation_deg": -37, "distance_mm": 3400})
    assert clock.run(STEP)["tools"]["Probe"]["reason"] == "outside_volume"
    clock.control({"type": "camera", "azimuth_deg": 50, "elevation_deg": -37, "distance_mm": 1600})
    clock.control({"type": "occluder", "present": True})
    state = clock.run(STEP)
    assert state["tools"]["Reamer"]["reason"] == "occluded" and state["occluder"]["boxes"]


def test_lost_tracking_during_registration_is_an_event_and_stops_the_dwell():
    clock = Clock(NavigationTrainer(seed=4))
    clock.control({"type": "probe", "action": "touch"})
    clock.control({"type": "camera", "azimuth_deg": -130, "elevation_deg": 10, "distance_mm": 1600})
    events = [e for _ in range(60) for e in clock.run(STEP)["events"]]
    assert any(e["kind"] == "tracking_lost" and "angle" in e["detail"] for e in events)
    assert clock.trainer.registration.acquired == {}


def test_a_fresh_session_has_no_tracking_to_lose_before_the_probe_is_used():
    clock = Clock(NavigationTrainer(seed=4))
    events = [e["kind"] for _ in range(30) for e in clock.run(STEP)["events"]]
    assert "tracking_lost" not in events and "target" in events  # no "tracking lost" toast on a new session's page


def test_retake_and_restart_count_and_reset():
    clock = Clock(NavigationTrainer(seed=5))
    with pytest.raises(ThrsimInputError, match="nothing to retake"):
        clock.control({"type": "registration", "action": "retake"})
    for _ in range(2):
        clock.control({"type": "probe", "action": "touch"})
        clock.run(0.7)
    assert len(clock.trainer.registration.acquired) == 2
    clock.control({"type": "registration", "action": "retake"})
    assert list(clock.trainer.registration.acquired) == ["asis_right"]
    assert clock.run(STEP)["registration"]["retakes"] == 1
    clock.control({"type": "registration", "action": "restart"})
    assert clock.run(STEP)["registration"]["acquired"] == []


def test_confirming_the_cup_needs_registration_then_records_it():
    clock = Clock(NavigationTrainer(seed=6))
    with pytest.raises(ThrsimInputError, match="registration"):
        clock.control({"type": "confirm_cup"})
    register_all(clock)
    clock.control({"type": "reamer", "inclination_deg": 40, "anteversion_deg": 15})
    clock.run(STEP)
    clock.control({"type": "confirm_cup"})
    cup = clock.run(STEP)["confirmed"]
    assert cup["inside"] and cup["inclination_deg"] == pytest.approx(40, abs=3)


def test_display_calibration_reports_its_residual_and_refuses_a_moving_view():
    clock = Clock(NavigationTrainer(seed=7))
    with pytest.raises(ThrsimInputError, match="display's pose"):
        clock.control({"type": "calibration", "action": "start"})
    viewer = np.eye(4)
    viewer[:3, 3] = [0.5, 1.0, 0.8]
    clock.control({"type": "viewer", "pose": viewer.ravel().tolist()})
    clock.control({"type": "calibration", "action": "start"})
    state = clock.run((CALIBRATION_SAMPLES + 2) * STEP)
    assert state["calibration"]["state"] == "done"
    assert 0 < state["calibration"]["result"]["translation_residual_rms_mm"] < 20
    clock.control({"type": "calibration", "action": "start"})
    for k in range(CALIBRATION_SAMPLES + 2):  # the trainee swings the view while it samples
        viewer[:3, 3] = [0.5 + 0.01 * k, 1.0, 0.8]
        clock.control({"type": "viewer", "pose": viewer.ravel().tolist()})
        state = clock.run(STEP)
    assert state["calibration"]["state"] == "refused" and "inconsistent" in state["calibration"]["message"]


def test_tracker_poses_drive_the_tools_and_go_stale():
    trainer = NavigationTrainer(seed=8)
    clock = Clock(trainer)
    pose = reamer_to_reference(trainer.targets, 35.0, 20.0)
    trainer.apply_pose("ReamerToReference", pose, clock.now)
    state = clock.run(STEP)
    assert state["tools"]["Reamer"]["source"] == "tracker"
    assert state["angles"]["radiographic"] == pytest.approx([35.0, 20.0], abs=1e-6)
    state = clock.run(1.0)
    assert state["tools"]["Reamer"]["reason"] == "stale" and state["angles"] is None
    # ReferenceToTracker puts the camera where the tracker is; *ToTracker poses are composed.
    camera = trainer.camera_pose.copy()
    trainer.apply_pose("ReferenceToTracker", invert(camera), clock.now)
    trainer.apply_pose("ProbeToTracker", invert(camera) @ trainer.tools["Reamer"].pose, clock.now)
    state = clock.run(STEP)
    assert state["camera"]["source"] == "tracker"
    assert np.allclose(trainer.tools["Probe"].pose, trainer.tools["Reamer"].pose)
    with pytest.raises(ThrsimInputError):
        trainer.apply_pose("ProbeToReference", np.diag([2.0, 1.0, 1.0, 1.0]), clock.now)


def test_left_hip_mirrors_the_scene_and_restarts_registration():
    clock = Clock(NavigationTrainer(seed=9))
    clock.control({"type": "probe", "action": "touch"})
    clock.run(0.7)
    clock.control({"type": "side", "value": "left"})
    state = clock.run(STEP)
    assert state["side"] == "left" and state["registration"]["acquired"] == []
    assert state["registration"]["current"] == "asis_left"
    scene = clock.trainer.scene()
    assert scene["acetabulum"]["left"][0] < 0 < scene["acetabulum"]["right"][0]
    clock.control({"type": "reamer", "inclination_deg": 40, "anteversion_deg": 15})
    assert clock.run(STEP)["zone"]["inside"]


@pytest.mark.parametrize(
    "message, reason",
    [
        ("{not json", "not JSON"),
        ("[1, 2]", "JSON object"),
        ('{"type": "warp"}', "unknown control type"),
        ('{"type": "reamer", "inclination_deg": 120, "anteversion_deg": 0}', "inclination_deg"),
        ('{"type": "camera", "azimuth_deg": 0, "elevation_deg": 0, "distance_mm": 1e9}', "distance_mm"),
        ('{"type": "viewer", "pose": [1, 2]}', "pose"),
        ('{"type": "probe", "action": "touch", "extra": 1}', "extra"),
        ('{"type": "reamer", "inclination_deg": NaN, "anteversion_deg": 0}', "inclination_deg"),
        ("x" * 20000, "exceeds"),
    ],
)
def test_malformed_or_out_of_range_controls_are_refused_with_a_reason(message, reason):
    with pytest.raises(ThrsimInputError, match=reason):
        parse_control(message)


def test_unknown_landmark_and_bad_viewer_pose_are_refused():
    clock = Clock(NavigationTrainer(seed=10))
    with pytest.raises(ThrsimInputError, match="unknown landmark"):
        clock.control({"type": "probe", "action": "touch", "landmark": "nose"})
    with pytest.raises(ThrsimInputError, match="viewer pose"):
        clock.control({"type": "viewer", "pose": [2.0] * 16})
    assert math.isfinite(clock.run(STEP)["time_s"])
