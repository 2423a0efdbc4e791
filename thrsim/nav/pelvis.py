"""A synthetic pelvis: 27 named landmarks in a pelvis model frame, in metres.

Model frame (RAS): +x toward the patient's right, +y anterior, +z superior, origin midway
between the ASIS; with no tilt the APP is the plane y = 0. The positions are plausible adult
values, not a measured specimen: they exist so that registration and angles can be exercised
end to end with a known ground truth. Landmarks specific to the operated hip (acetabular rim,
ischium) are on the ``side`` given; the left pelvis is the mirror of the right.
"""

from __future__ import annotations

import math

import numpy as np

from thrsim.config import Side
from thrsim.nav.bone_frame import check_side, on_side

ACETABULUM_CENTRE_RIGHT = np.array([0.085, -0.035, -0.055])
ACETABULUM_RIM_RADIUS = 0.026
# The native acetabulum opens at roughly this radiographic orientation; only the rim's shape
# depends on it.
_NATIVE_INCLINATION_DEG, _NATIVE_ANTEVERSION_DEG = 50.0, 20.0
_RIM_POINTS = 12

_BILATERAL_RIGHT = {
    "asis_right": (0.115, 0.0, 0.0),
    "asis_left": (-0.115, 0.0, 0.0),
    "pubic_right": (0.022, 0.0, -0.088),
    "pubic_left": (-0.022, 0.0, -0.088),
    "pubic_symphysis": (0.0, -0.006, -0.094),
    "aiis_right": (0.104, -0.022, -0.036),
    "aiis_left": (-0.104, -0.022, -0.036),
    "iliac_tubercle_right": (0.126, -0.048, 0.052),
    "iliac_tubercle_left": (-0.126, -0.048, 0.052),
    "iliac_crest_posterior_right": (0.082, -0.118, 0.071),
    "iliac_crest_posterior_left": (-0.082, -0.118, 0.071),
    "psis_right": (0.041, -0.168, 0.028),
    "psis_left": (-0.041, -0.168, 0.028),
    "ischial_spine": (0.058, -0.102, -0.062),
    "ischial_tuberosity": (0.071, -0.071, -0.121),
}


def native_axis_right() -> np.ndarray:
    """Unit axis out of the right native acetabulum (model frame): the rim lies across it."""
    inclination = math.radians(_NATIVE_INCLINATION_DEG)
    anteversion = math.radians(_NATIVE_ANTEVERSION_DEG)
    # (lat, ant, inf) = (+x, +y, −z) for the right hip.
    return np.array([math.cos(anteversion) * math.sin(inclination), math.sin(anteversion), -math.cos(anteversion) * math.cos(inclination)])


def _rim_right() -> dict[str, np.ndarray]:
    axis = native_axis_right()
    first = np.cross(axis, [0.0, 1.0, 0.0])
    first /= np.linalg.norm(first)
    second = np.cross(axis, first)
    rim = {}
    for k in range(_RIM_POINTS):
        phi = 2.0 * math.pi * k / _RIM_POINTS
        rim[f"rim_{30 * k:03d}"] = ACETABULUM_CENTRE_RIGHT + ACETABULUM_RIM_RADIUS * (math.cos(phi) * first + math.sin(phi) * second)
    return rim


def _mirror_name(name: str) -> str:
    if name.endswith("_right"):
        return name[: -len("_right")] + "_left"
    if name.endswith("_left"):
        return name[: -len("_left")] + "_right"
    return name


def synthetic_pelvis_landmarks(side: Side = "right") -> dict[str, np.ndarray]:
    """The 27 landmarks of the synthetic pelvis in the model frame (m), in acquisition order."""
    check_side(side)
    right = {name: np.array(p, dtype=float) for name, p in _BILATERAL_RIGHT.items()} | _rim_right()
    if side == "right":
        return right
    return {_mirror_name(name): on_side(point, side) for name, point in right.items()}


def acetabulum_centre(side: Side = "right") -> np.ndarray:
    return on_side(ACETABULUM_CENTRE_RIGHT, side)
