"""APP frame and Murray's cup angles: the 40/15 check on both sides, the pitfalls' figures,
the thesis's eq. 1–2, conversions round-tripping, and one-line errors for bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from thrsim.errors import ThrsimInputError
from thrsim.nav import angles_in_frame, app_frame, convert_angles, cup_angles, local_axis_from_angles, synthetic_pelvis_landmarks
from thrsim.nav.anatomy import DEFINITIONS, angles_from_local

pytestmark = pytest.mark.timeout(60)

# Patient axes of the synthetic pelvis model frame (RAS), independent of app_frame.
ANTERIOR = np.array([0.0, 1.0, 0.0])
INFERIOR = np.array([0.0, 0.0, -1.0])


def lateral(side: str) -> np.ndarray:
    return np.array([1.0 if side == "right" else -1.0, 0.0, 0.0])


def radiographic_axis(side: str, inclination_deg: float, anteversion_deg: float) -> np.ndarray:
    """Cup axis built by hand from the radiographic definition in the model frame."""
    ri, ra = math.radians(inclination_deg), math.radians(anteversion_deg)
    return math.cos(ra) * math.sin(ri) * lateral(side) + math.sin(ra) * ANTERIOR + math.cos(ra) * math.cos(ri) * INFERIOR


def moved(landmarks: dict, rotation: Rotation, shift: np.ndarray, scale: float = 1.0) -> dict:
    return {name: rotation.apply(point * scale) + shift for name, point in landmarks.items()}


@pytest.mark.parametrize("side", ["right", "left"])
def test_cup_angles_40_15_in_synthetic_pelvis(side):
    landmarks = synthetic_pelvis_landmarks(side)
    inclination, anteversion = cup_angles(radiographic_axis(side, 40.0, 15.0), landmarks, side=side)
    assert inclination == pytest.approx(40.0, abs=1e-9)
    assert anteversion == pytest.approx(15.0, abs=1e-9)


@pytest.mark.parametrize("side", ["right", "left"])
def test_cup_angles_independent_of_pelvis_pose_and_units(side):
    rotation = Rotation.from_euler("zyx", [63.0, -21.0, 12.0], degrees=True)
    landmarks_mm = moved(synthetic_pelvis_landmarks(side), rotation, np.array([120.0, -40.0, 900.0]), scale=1000.0)
    axis = rotation.apply(radiographic_axis(side, 40.0, 15.0))
    assert cup_angles(axis, landmarks_mm, side=side) == pytest.approx((40.0, 15.0), abs=1e-9)


def test_lewinnek_centre_in_other_definitions_matches_notes():
    landmarks = synthetic_pelvis_landmarks("right")
    axis = radiographic_axis("right", 40.0, 15.0)
    assert cup_angles(axis, landmarks, definition="operative") == pytest.approx((38.4, 19.3), abs=0.05)
    assert cup_angles(axis, landmarks, definition="anatomic") == pytest.approx((42.3, 22.6), abs=0.05)


def test_thesis_equations_are_radiographic_and_unnormalised_projection_is_anatomic():
    frame = app_frame(synthetic_pelvis_landmarks("right"))
    axis = radiographic_axis("right", 40.0, 15.0)
    normal, longitudinal = frame.anterior, frame.inferior
    anteversion = 90.0 - math.degrees(math.acos(normal @ axis))  # eq. (1)
    projection = axis - (axis @ normal) * normal
    inclination = math.degrees(math.acos(longitudinal @ (projection / np.linalg.norm(projection))))  # eq. (2)
    assert (inclination, anteversion) == pytest.approx((40.0, 15.0), abs=1e-9)
    pitfall = math.degrees(math.acos(longitudinal @ projection))  # forgetting to normalise
    assert pitfall == pytest.approx(42.27, abs=0.01)
    assert pitfall == pytest.approx(cup_angles(axis, synthetic_pelvis_landmarks("right"), definition="anatomic")[0])


def test_app_frame_axes_are_orthonormal_and_left_is_mirror():
    right = app_frame(synthetic_pelvis_landmarks("right"), "right")
    left = app_frame(synthetic_pelvis_landmarks("left"), "left")
    assert right.axes @ right.axes.T == pytest.approx(np.eye(3))
    # (lateral, anterior, inferior) is left-handed for the right hip; the left hip's mirror is not.
    assert np.linalg.det(right.axes) == pytest.approx(-1.0)
    assert np.linalg.det(left.axes) == pytest.approx(1.0)
    assert right.lateral == pytest.approx([1, 0, 0]) and left.lateral == pytest.approx([-1, 0, 0])
    assert right.anterior == pytest.approx(ANTERIOR) and right.inferior == pytest.approx(INFERIOR)


def test_three_point_plane_equals_standard_for_symmetric_pelvis_and_shifts_for_asymmetric():
    landmarks = synthetic_pelvis_landmarks("right")
    axis = radiographic_axis("right", 40.0, 15.0)
    standard = app_frame(landmarks, plane="standard")
    three = app_frame(landmarks, plane="three_point")
    assert three.axes == pytest.approx(standard.axes)
    asymmetric = dict(landmarks, pubic_right=landmarks["pubic_right"] + [0.0, 0.005, 0.0])  # 5 mm anterior
    shift = angles_in_frame(axis, app_frame(asymmetric, plane="three_point"))[1] - angles_in_frame(axis, app_frame(asymmetric))[1]
    assert 0.5 < abs(shift) < 3.0


def test_pelvic_tilt_moves_anteversion_when_frame_is_not_the_app():
    # Tilt the pelvis 10° about the lateral axis while the cup stays fixed in the room: measured
    # in the APP the anteversion changes by about the tilt (about 0.75° per degree for real cups).
    landmarks = synthetic_pelvis_landmarks("right")
    tilt = Rotation.from_euler("x", 10.0, degrees=True)
    tilted = moved(landmarks, tilt, np.zeros(3))
    axis = radiographic_axis("right", 40.0, 15.0)
    change = cup_angles(axis, tilted)[1] - 15.0
    assert 5.0 < abs(change) < 12.0


angle_pairs = st.tuples(st.floats(1.0, 89.0), st.floats(-80.0, 80.0))


@settings(max_examples=150, deadline=None)
@given(angles=angle_pairs, source=st.sampled_from(DEFINITIONS), target=st.sampled_from(DEFINITIONS))
def test_conversions_round_trip(angles, source, target):
    there = convert_angles(*angles, source, target)
    back = convert_angles(*there, target, source)
    assert back == pytest.approx(angles, abs=1e-7)


@settings(max_examples=100, deadline=None)
@given(angles=angle_pairs)
def test_conversion_identities_from_notes(angles):
    ri, ra = (math.radians(a) for a in angles)
    oi, oa = (math.radians(a) for a in convert_angles(*angles, "radiographic", "operative"))
    ai, aa = (math.radians(a) for a in convert_angles(*angles, "radiographic", "anatomic"))
    assert math.tan(aa) == pytest.approx(math.tan(ra) / math.sin(ri), rel=1e-6, abs=1e-9)
    assert math.tan(oa) == pytest.approx(math.tan(ra) / math.cos(ri), rel=1e-6, abs=1e-9)
    assert math.cos(ai) == pytest.approx(math.cos(ra) * math.cos(ri), rel=1e-9, abs=1e-12)
    assert math.sin(oi) == pytest.approx(math.cos(ra) * math.sin(ri), rel=1e-9, abs=1e-12)


@settings(max_examples=100, deadline=None)
@given(
    angles=angle_pairs,
    definition=st.sampled_from(DEFINITIONS),
    side=st.sampled_from(["right", "left"]),
    quaternion=st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
)
def test_cup_angles_recovers_built_axis_under_any_pelvis_pose(angles, definition, side, quaternion):
    rotation = Rotation.from_quat(quaternion)
    landmarks = moved(synthetic_pelvis_landmarks(side), rotation, np.array([0.3, -0.2, 1.1]))
    local = local_axis_from_angles(*angles, definition)
    axis = rotation.apply(local[0] * lateral(side) + local[1] * ANTERIOR + local[2] * INFERIOR)
    assert cup_angles(axis, landmarks, side=side, definition=definition) == pytest.approx(angles, abs=1e-6)


GOOD = synthetic_pelvis_landmarks("right")
AXIS = radiographic_axis("right", 40.0, 15.0)


@pytest.mark.parametrize(
    "axis, landmarks, kwargs, message",
    [
        ([np.nan, 0.0, 1.0], GOOD, {}, "not finite"),
        ([0.0, 0.0, 0.0], GOOD, {}, "zero vector"),
        ([0.0, 0.0, 2.0], GOOD, {}, "unit vector"),
        ([1.0, 0.0], GOOD, {}, "3-vector"),
        ("up", GOOD, {}, "3-vector"),
        (AXIS, {k: v for k, v in GOOD.items() if k != "pubic_left"}, {}, "'pubic_left' is missing"),
        (AXIS, dict(GOOD, asis_left=[np.nan, 0, 0]), {}, "not finite"),
        (AXIS, dict(GOOD, asis_left=GOOD["asis_right"]), {}, "coincide"),
        (AXIS, dict(GOOD, pubic_right=[0.05, 0, 0], pubic_left=[-0.05, 0, 0]), {}, "collinear"),
        (AXIS, GOOD, {"side": "middle"}, "side must be"),
        (AXIS, GOOD, {"definition": "surgical"}, "definition must be"),
        (-AXIS, GOOD, {}, "points medially"),
    ],
)
def test_bad_input_raises_one_line_error(axis, landmarks, kwargs, message):
    with pytest.raises(ThrsimInputError, match=message) as info:
        cup_angles(axis, landmarks, **kwargs)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("angles", [(-1.0, 15.0), (91.0, 15.0), (40.0, 95.0), (math.nan, 15.0), (40.0, math.inf)])
def test_out_of_range_angles_are_refused(angles):
    with pytest.raises(ThrsimInputError, match="must lie in"):
        convert_angles(*angles, "radiographic", "operative")


def test_angles_from_local_rejects_unknown_definition():
    with pytest.raises(ThrsimInputError, match="definition"):
        angles_from_local(np.array([0.6, 0.2, 0.77]), "clinical")
