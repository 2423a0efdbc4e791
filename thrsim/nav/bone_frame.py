"""The bone frame in the pelvis: where the trainer places the bone patch, and the reamer's aim in both frames.

The case files, ``thrsim fem`` and ``thrsim ream`` aim the reamer by γ, θ in the bone frame: the
axis D = (sin γ cos θ, sin γ sin θ, −cos γ) points into the bone, γ is its angle from the socket
axis (+z, out of the acetabulum). The trainer shows the cup's clinical angles instead (Murray's
radiographic inclination and anteversion in the anterior pelvic plane). It places the bone frame
in the hip's APP frame with +z along the cup axis at the safe zone's centre (40°, 15°), so aiming
at the zone's centre is γ = 0, and the cup axis (out of the acetabulum) is −D. A left hip's APP
frame is the mirror of a right one's, so one patch serves both: the same clinical angles give the
same γ, θ on either side. The mirror itself (:func:`on_side`, across x = 0 in the pelvis model
frame and the bone frame alike) is applied where a left hip's points enter or leave a right-hip
computation, and only there. Pure numerics, no I/O.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from thrsim.config import SIDES, Orientation, SafeZone, Side
from thrsim.errors import ThrsimInputError
from thrsim.nav.anatomy import angles_from_local, local_axis_from_angles

#: a left hip is the mirror of a right one across x = 0 (the sagittal plane of the pelvis model
#: frame; the bone frame's x = 0 plane)
MIRROR = np.array([-1.0, 1.0, 1.0])


def check_side(side: str) -> Side:
    """``side`` when it is a hip side; ThrsimInputError otherwise."""
    if side not in SIDES:
        raise ThrsimInputError(f"must be right or left, got {side!r}", "side")
    return side


def other_side(side: Side) -> Side:
    return "left" if side == "right" else "right"


def on_side(right: ArrayLike, side: Side) -> np.ndarray:
    """Points or directions (…×3) of a right hip as they are on ``side``; the mirror is its own
    inverse, so a left hip's given here come back as the right hip's."""
    right = np.asarray(right, dtype=np.float64)
    return right * MIRROR if side == "left" else right


def patch_in_app(zone: SafeZone = SafeZone()) -> np.ndarray:
    """3×3: the bone patch's axes (columns) in APP (lateral, anterior, inferior) components.

    (lateral, anterior, inferior) is a left-handed triple for a right hip, so the patch's axes are
    written left-handed in it: placed in a right pelvis the patch is then rotated, not mirrored,
    and in a left pelvis (whose APP frame is the mirror) it is mirrored, as a left hip is.
    """
    z = local_axis_from_angles(zone.inclination_deg, zone.anteversion_deg)
    inferior = np.array([0.0, 0.0, 1.0])
    x = inferior - (inferior @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(x, z), z])


def angles_of(axis: np.ndarray) -> tuple[float, float]:
    """(γ, θ) in degrees of a unit axis D = (sin γ cos θ, sin γ sin θ, −cos γ), as in the case files."""
    gamma = math.degrees(math.acos(float(np.clip(-axis[2], -1.0, 1.0))))
    theta = math.degrees(math.atan2(axis[1], axis[0])) % 360.0 if gamma > 1e-9 else 0.0
    return gamma, theta


def reamer_axis_from_cup(cup_axis_app: np.ndarray, zone: SafeZone = SafeZone()) -> np.ndarray:
    """D in the bone frame (into the bone) of a cup axis given in APP (lateral, anterior, inferior) components."""
    return -(patch_in_app(zone).T @ np.asarray(cup_axis_app, dtype=np.float64))


def bone_angles_from_cup(inclination_deg: float, anteversion_deg: float, zone: SafeZone = SafeZone()) -> tuple[float, float]:
    """(γ, θ) in degrees of the reamer aimed at radiographic cup angles (inclination [0, 90], anteversion [−90, 90])."""
    return angles_of(reamer_axis_from_cup(local_axis_from_angles(inclination_deg, anteversion_deg), zone))


def cup_angles_from_bone(gamma_deg: float, theta_deg: float, zone: SafeZone = SafeZone()) -> tuple[float, float] | None:
    """Radiographic (inclination, anteversion) in degrees of the reamer aimed at (γ, θ); None where the
    cup axis would point medially (into the pelvis), which has no clinical angles."""
    axis = np.array(Orientation(inclination_deg=gamma_deg, anteversion_deg=theta_deg).reamer_axis)
    cup_axis_app = -(patch_in_app(zone) @ axis)
    if cup_axis_app[0] < 0.0:
        return None
    return angles_from_local(cup_axis_app)
