"""Lewinnek safe zone (radiographic 40 ± 10° inclination, 15 ± 10° anteversion) and ray colour.

The distance to the zone is the Euclidean distance, in degrees, from the (inclination,
anteversion) point to the zone's rectangle in angle space: 0 inside, growing with how far a
trainee must still tilt the reamer. The ray is green inside, amber within the warning margin,
red beyond — one glance, as in the thesis's trainer [3.1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from thrsim.config import SafeZone

COLOURS: dict[str, tuple[int, int, int]] = {
    "green": (0, 200, 80),
    "amber": (255, 176, 0),
    "red": (220, 30, 30),
}


@dataclass(frozen=True)
class SafeZoneStatus:
    inside: bool
    distance_deg: float
    colour: str

    @property
    def rgb(self) -> tuple[int, int, int]:
        return COLOURS[self.colour]

    def as_dict(self) -> dict:
        return {"inside": self.inside, "distance_deg": self.distance_deg, "colour": self.colour, "rgb": list(self.rgb)}


def _outside_by(value: float, centre: float, tolerance: float) -> float:
    return max(0.0, abs(value - centre) - tolerance)


def safe_zone_status(inclination_deg: float, anteversion_deg: float, zone: SafeZone = SafeZone()) -> SafeZoneStatus:
    """Where radiographic (inclination, anteversion) in degrees lies relative to ``zone``."""
    distance = math.hypot(
        _outside_by(inclination_deg, zone.inclination_deg, zone.inclination_tolerance_deg),
        _outside_by(anteversion_deg, zone.anteversion_deg, zone.anteversion_tolerance_deg),
    )
    if distance == 0.0:
        colour = "green"
    elif distance <= zone.warning_margin_deg:
        colour = "amber"
    else:
        colour = "red"
    return SafeZoneStatus(inside=distance == 0.0, distance_deg=distance, colour=colour)
