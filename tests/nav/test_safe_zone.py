"""Lewinnek safe zone: inside/outside, distance in angle space, ray colour."""

from __future__ import annotations

import math

import pytest

from thrsim.config import SafeZone
from thrsim.nav import safe_zone_status

pytestmark = pytest.mark.timeout(30)


@pytest.mark.parametrize("angles", [(40.0, 15.0), (30.0, 5.0), (50.0, 25.0), (30.0, 25.0)])
def test_inside_and_on_the_border_is_green_at_zero_distance(angles):
    status = safe_zone_status(*angles)
    assert status.inside and status.distance_deg == 0.0 and status.colour == "green"


def test_distance_is_euclidean_to_the_rectangle():
    assert safe_zone_status(53.0, 15.0).distance_deg == pytest.approx(3.0)
    assert safe_zone_status(40.0, 1.0).distance_deg == pytest.approx(4.0)
    assert safe_zone_status(53.0, 29.0).distance_deg == pytest.approx(5.0)  # corner: 3-4-5


def test_colour_bands():
    assert safe_zone_status(53.0, 15.0).colour == "amber"
    assert safe_zone_status(60.0, 15.0).colour == "red"
    assert safe_zone_status(60.0, 15.0).rgb == (220, 30, 30)


def test_configurable_zone():
    zone = SafeZone(
        inclination_deg=45.0, inclination_tolerance_deg=5.0, anteversion_deg=20.0, anteversion_tolerance_deg=5.0, warning_margin_deg=1.0
    )
    assert safe_zone_status(40.0, 15.0, zone).inside  # the corner of this zone
    status = safe_zone_status(38.0, 20.0, zone)
    assert status.distance_deg == pytest.approx(2.0) and status.colour == "red"
    assert math.isclose(safe_zone_status(45.0, 20.0, zone).distance_deg, 0.0)
