"""Navigation state from streamed poses and force: angles, safe zone, tracking status, staleness."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from thrsim.errors import ThrsimInputError
from thrsim.nav import TrackerState
from thrsim.nav.rigid import make_pose

pytestmark = pytest.mark.timeout(30)


def reamer_pose(inclination_deg: float, anteversion_deg: float, side: str = "right") -> np.ndarray:
    """Reamer in the synthetic pelvis frame: its local +z is the cup axis (lat, ant, inf)."""
    ri, ra = np.radians(inclination_deg), np.radians(anteversion_deg)
    lateral = np.array([1.0 if side == "right" else -1.0, 0, 0])
    axis = np.cos(ra) * np.sin(ri) * lateral + np.sin(ra) * np.array([0, 1.0, 0]) + np.cos(ra) * np.cos(ri) * np.array([0, 0, -1.0])
    x = np.cross([0.0, 1.0, 0.0], axis)
    x /= np.linalg.norm(x)
    return make_pose(np.column_stack([x, np.cross(axis, x), axis]), [0.085, -0.035, -0.055])


@pytest.mark.parametrize("side", ["right", "left"])
def test_state_from_reamer_to_reference(side):
    tracker = TrackerState(side=side)
    tracker.update_pose("ReamerToReference", reamer_pose(40, 15, side), 10.0)
    tracker.update_force(np.array([0.0, 0.0, 230.0]), 10.0)
    state = tracker.state(10.1)
    assert (state["inclination_deg"], state["anteversion_deg"]) == pytest.approx((40.0, 15.0))
    assert state["in_safe_zone"] and state["ray_colour"] == "green" and state["distance_to_zone_deg"] == 0.0
    assert state["operative_deg"] == pytest.approx([38.38, 19.28], abs=0.01)
    assert state["force_n"] == pytest.approx(230.0) and state["force_age_s"] == pytest.approx(0.1)
    assert state["tracking"] == {"Reamer": "tracked", "Reference": "missing"}
    assert state["reamer_position_mm"] == pytest.approx([85.0, -35.0, -55.0])


def test_state_composes_tracker_poses_and_reports_camera_visibility():
    tracker = TrackerState()
    world_from_reference = make_pose(Rotation.from_euler("x", 180, degrees=True), [0.0, 0.0, 1.5])
    tracker.update_pose("ReferenceToTracker", world_from_reference, 0.0)
    tracker.update_pose("ReamerToTracker", world_from_reference @ reamer_pose(55, 15), 0.0)
    state = tracker.state(0.0)
    assert (state["inclination_deg"], state["anteversion_deg"]) == pytest.approx((55.0, 15.0))
    assert state["ray_colour"] == "amber" and state["distance_to_zone_deg"] == pytest.approx(5.0)
    assert state["tracking"]["Reference"] == "tracked"
    assert state["tracking"]["Reamer"] in ("tracked", "angle")  # the reamer plate faces along the cup axis
    tracker.update_pose("ReferenceToTracker", make_pose(np.eye(3), [0.0, 0.0, 3.0]), 0.1)
    assert tracker.state(0.1)["tracking"]["Reference"] == "outside_volume"


def test_stale_pose_and_medial_axis_give_no_angles_with_a_note():
    tracker = TrackerState(stale_after_s=0.5)
    tracker.update_pose("ReamerToReference", reamer_pose(40, 15), 0.0)
    stale = tracker.state(1.0)
    assert stale["inclination_deg"] is None and stale["note"] == "no fresh reamer pose"
    assert stale["tracking"]["Reamer"] == "stale"
    flipped = reamer_pose(40, 15) @ make_pose(Rotation.from_euler("x", 180, degrees=True), [0, 0, 0])
    tracker.update_pose("ReamerToReference", flipped, 2.0)
    assert "points medially" in tracker.state(2.0)["note"]


def test_bad_pose_and_force_are_refused():
    tracker = TrackerState()
    with pytest.raises(ThrsimInputError, match="NaN"):
        tracker.update_pose("ReamerToReference", np.full((4, 4), np.nan), 0.0)
    with pytest.raises(ThrsimInputError, match="not finite"):
        tracker.update_force(np.array([np.inf]), 0.0)
