"""Anterior pelvic plane (APP) frame and cup/reamer angles (Murray 1993).

Pure numerics, no I/O. Landmarks and axes may be in any consistent length unit: only directions
matter. Angles cross this module's public functions in degrees because they are clinical
quantities read by people; radians stay inside. The APP frame of one hip has axes (lateral,
anterior, inferior) (:class:`AppFrame`); in it a cup axis gives Murray's radiographic, operative
and anatomic angles (:func:`angles_from_local`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from thrsim.config import SIDES
from thrsim.errors import ThrsimInputError

Definition = Literal["radiographic", "operative", "anatomic"]
Plane = Literal["standard", "three_point"]

DEFINITIONS: tuple[str, ...] = ("radiographic", "operative", "anatomic")
APP_LANDMARKS: tuple[str, ...] = ("asis_right", "asis_left", "pubic_right", "pubic_left")

# Loose enough for axes typed with three decimals; anything further off is a caller's
# mistake (an unnormalised direction, a position passed as an axis).
_UNIT_TOLERANCE = 1e-3
# sin of the smallest angle between the ASIS line and the pubic direction still called a plane.
_COLLINEAR_SINE = 1e-6


@dataclass(frozen=True)
class AppFrame:
    """The APP frame of one hip: origin (landmark units) and unit axes as rows of ``axes``.

    * lateral: from the contralateral to the operated ASIS (the left hip's frame is the mirror of
      the right's across the sagittal plane, so one set of formulas serves both sides);
    * inferior: in the APP, perpendicular to the ASIS line, toward the pubic tubercles;
    * anterior: normal of the APP, out of the body.
    """

    origin: np.ndarray
    axes: np.ndarray  # rows: lateral, anterior, inferior (world coordinates)
    side: str

    @property
    def lateral(self) -> np.ndarray:
        return self.axes[0]

    @property
    def anterior(self) -> np.ndarray:
        return self.axes[1]

    @property
    def inferior(self) -> np.ndarray:
        return self.axes[2]

    def to_local(self, direction: np.ndarray) -> np.ndarray:
        """A world direction in (lateral, anterior, inferior) components."""
        return self.axes @ np.asarray(direction, dtype=float)

    def to_world(self, local_direction: np.ndarray) -> np.ndarray:
        """A (lateral, anterior, inferior) direction back in world coordinates."""
        return self.axes.T @ np.asarray(local_direction, dtype=float)


def _check_choice(value: str, choices: tuple[str, ...], what: str) -> None:
    if value not in choices:
        raise ThrsimInputError(f"{what} must be one of {', '.join(choices)}; got {value!r}")


def _point(landmarks: Mapping[str, object], name: str) -> np.ndarray:
    if name not in landmarks:
        raise ThrsimInputError(f"landmark {name!r} is missing (need {', '.join(APP_LANDMARKS)})")
    try:
        point = np.asarray(landmarks[name], dtype=float)
    except (TypeError, ValueError):
        raise ThrsimInputError(f"landmark {name!r} is not a 3-vector of numbers") from None
    if point.shape != (3,):
        raise ThrsimInputError(f"landmark {name!r} must be a 3-vector, got shape {point.shape}")
    if not np.all(np.isfinite(point)):
        raise ThrsimInputError(f"landmark {name!r} is not finite: {point.tolist()}")
    return point


def app_frame(landmarks: Mapping[str, object], side: str = "right", plane: str = "standard") -> AppFrame:
    """The APP frame of the ``side`` hip from pelvic landmarks.

    ``plane="standard"``: both ASIS and the midpoint of both pubic tubercles.
    ``plane="three_point"``: the thesis's plane through both ASIS and the ipsilateral pubic
    tubercle only (an asymmetric pelvis then shifts anteversion ~1.2° per 5 mm).
    """
    _check_choice(side, SIDES, "side")
    _check_choice(plane, ("standard", "three_point"), "plane")
    asis_right = _point(landmarks, "asis_right")
    asis_left = _point(landmarks, "asis_left")
    if plane == "standard":
        pubic = 0.5 * (_point(landmarks, "pubic_right") + _point(landmarks, "pubic_left"))
    else:
        pubic = _point(landmarks, f"pubic_{side}")

    asis_line = asis_right - asis_left
    width = float(np.linalg.norm(asis_line))
    if width == 0.0:
        raise ThrsimInputError("landmarks asis_right and asis_left coincide: no APP frame")
    to_right = asis_line / width
    asis_mid = 0.5 * (asis_right + asis_left)
    down = pubic - asis_mid
    down_length = float(np.linalg.norm(down))
    inferior = down - (down @ to_right) * to_right
    if down_length == 0.0 or np.linalg.norm(inferior) <= _COLLINEAR_SINE * down_length:
        raise ThrsimInputError("APP landmarks are collinear (pubic point on the ASIS line): no plane")
    inferior /= np.linalg.norm(inferior)
    # Right-handed patient axes: right × inferior = anterior. The labels right/left carry the
    # handedness; the left hip then flips only the lateral axis (the mirror).
    anterior = np.cross(to_right, inferior)
    lateral = to_right if side == "right" else -to_right
    return AppFrame(origin=asis_mid, axes=np.vstack([lateral, anterior, inferior]), side=side)


def _unit_axis(axis: object, what: str = "axis") -> np.ndarray:
    try:
        vector = np.asarray(axis, dtype=float)
    except (TypeError, ValueError):
        raise ThrsimInputError(f"{what} is not a 3-vector of numbers") from None
    if vector.shape != (3,):
        raise ThrsimInputError(f"{what} must be a 3-vector, got shape {vector.shape}")
    if not np.all(np.isfinite(vector)):
        raise ThrsimInputError(f"{what} is not finite: {vector.tolist()}")
    norm = float(np.linalg.norm(vector))
    if norm == 0.0:
        raise ThrsimInputError(f"{what} is the zero vector")
    if abs(norm - 1.0) > _UNIT_TOLERANCE:
        raise ThrsimInputError(f"{what} must be a unit vector, its length is {norm:.6g}")
    return vector / norm


def angles_from_local(local_axis: np.ndarray, definition: str = "radiographic") -> tuple[float, float]:
    """(inclination_deg, anteversion_deg) of a unit cup axis ``a`` (pointing out of the acetabulum)
    given in (lat, ant, inf) components, in Murray's definitions (JBJS Br 1993):

    * radiographic: RI = atan2(a_lat, a_inf), RA = asin(a_ant): the thesis's eq. 1–2 (projected
      vector normalised; not normalising gives the anatomic inclination instead);
    * operative: OI = asin(a_lat), OA = atan2(a_ant, a_inf);
    * anatomic: AI = acos(a_inf), AA = atan2(a_ant, a_lat).
    """
    _check_choice(definition, DEFINITIONS, "definition")
    lat, ant, inf = (float(np.clip(c, -1.0, 1.0)) for c in local_axis)
    if lat < 0.0:
        raise ThrsimInputError("axis points medially (into the pelvis); give the cup axis pointing out of the acetabulum")
    if definition == "radiographic":
        inclination, anteversion = math.atan2(lat, inf), math.asin(ant)
    elif definition == "operative":
        inclination, anteversion = math.asin(lat), math.atan2(ant, inf)
    else:
        inclination, anteversion = math.acos(inf), math.atan2(ant, lat)
    return math.degrees(inclination), math.degrees(anteversion)


def _check_angles(inclination_deg: float, anteversion_deg: float) -> None:
    for name, value, low, high in (
        ("inclination", inclination_deg, 0.0, 90.0),
        ("anteversion", anteversion_deg, -90.0, 90.0),
    ):
        if not math.isfinite(value) or not low <= value <= high:
            raise ThrsimInputError(f"{name} must lie in [{low:g}, {high:g}] degrees, got {value}")


def local_axis_from_angles(inclination_deg: float, anteversion_deg: float, definition: str = "radiographic") -> np.ndarray:
    """The unit cup axis in (lat, ant, inf) components for angles in ``definition``.

    Inclination in [0, 90], anteversion in [-90, 90] degrees (retroversion negative).
    """
    _check_choice(definition, DEFINITIONS, "definition")
    _check_angles(inclination_deg, anteversion_deg)
    inclination, anteversion = math.radians(inclination_deg), math.radians(anteversion_deg)
    if definition == "radiographic":
        lat = math.cos(anteversion) * math.sin(inclination)
        ant = math.sin(anteversion)
        inf = math.cos(anteversion) * math.cos(inclination)
    elif definition == "operative":
        lat = math.sin(inclination)
        ant = math.cos(inclination) * math.sin(anteversion)
        inf = math.cos(inclination) * math.cos(anteversion)
    else:
        lat = math.sin(inclination) * math.cos(anteversion)
        ant = math.sin(inclination) * math.sin(anteversion)
        inf = math.cos(inclination)
    return np.array([lat, ant, inf])


def convert_angles(inclination_deg: float, anteversion_deg: float, source: str, target: str) -> tuple[float, float]:
    """Convert (inclination, anteversion) between Murray's definitions through the cup axis.

    Equivalent to tan AA = tan RA / sin RI, tan OA = tan RA / cos RI, cos AI = cos RA · cos RI.
    """
    _check_choice(target, DEFINITIONS, "target definition")
    return angles_from_local(local_axis_from_angles(inclination_deg, anteversion_deg, source), target)


def angles_in_frame(axis: object, frame: AppFrame, definition: str = "radiographic") -> tuple[float, float]:
    """(inclination_deg, anteversion_deg) of a world unit cup axis in an APP frame."""
    return angles_from_local(frame.to_local(_unit_axis(axis)), definition)


def cup_angles(
    axis: object,
    landmarks: Mapping[str, object],
    side: str = "right",
    definition: str = "radiographic",
) -> tuple[float, float]:
    """Cup (or reamer) inclination and anteversion in degrees, in the standard APP.

    ``axis``: unit 3-vector, the cup axis pointing out of the acetabulum (the reamer axis D of
    the case files points into the bone: pass −D). ``landmarks``: mapping with ``asis_right``,
    ``asis_left``, ``pubic_right``, ``pubic_left`` (3-vectors, any consistent unit, same frame
    as ``axis``). Raises :class:`ThrsimInputError` with a one-line reason on bad input.
    """
    _check_choice(definition, DEFINITIONS, "definition")
    return angles_in_frame(axis, app_frame(landmarks, side=side), definition)
