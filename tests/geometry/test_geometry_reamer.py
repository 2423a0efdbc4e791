"""Reamer head and tooth layout, mass, and the reamer-to-bone frame rotation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from thrsim.config import Orientation, ReamerConfig
from thrsim.geometry.reamer import GOLDEN_ANGLE, build_reamer, frame_rotation


@pytest.fixture(scope="module")
def reamer():
    return build_reamer()


def test_tooth_count_and_distinct_polar_angles(reamer):
    assert reamer.tooth_count == 56
    centres = reamer.tooth_polar_centre
    assert len(np.unique(np.round(centres, 12))) == 56
    assert np.all(np.diff(centres) > 0)
    assert math.degrees(centres.min()) == pytest.approx(3.0, abs=1.0)
    assert len(np.unique(np.round(reamer.tooth_azimuth, 12))) == 56
    np.testing.assert_allclose(np.diff(reamer.tooth_azimuth[:2]), GOLDEN_ANGLE)


def test_tooth_arcs_stay_on_the_dome(reamer):
    start, end = reamer.tooth_polar_start, reamer.tooth_polar_end
    assert np.all(start >= 0) and np.all(end <= math.pi / 2 + 1e-15)
    assert np.all(end > start)
    # every edge is tooth_length long unless clipped at the pole or the equator
    length = (end - start) * reamer.edge_axis_radius
    clipped = (start == 0) | (end == math.pi / 2)
    np.testing.assert_allclose(length[~clipped], 3.0e-3)
    assert np.all(length[clipped] < 3.0e-3 + 1e-12)

    # no bald rings: every polar angle from the pole to the last tooth is swept by an edge,
    # and away from the pole and the rim by several (arc length ≫ polar spacing)
    def coverage(lo_deg, hi_deg):
        polar = np.radians(np.linspace(lo_deg, hi_deg, 2001))
        return ((polar[:, None] >= start[None]) & (polar[:, None] <= end[None])).sum(axis=1)

    assert coverage(0.0, 86.0).min() >= 1
    assert coverage(10.0, 80.0).min() >= 4


def test_edges_stand_proud_by_the_protrusion(reamer):
    assert reamer.head_radius == pytest.approx(22.5e-3)
    assert reamer.outer_radius - reamer.head_radius == pytest.approx(0.4e-3)
    assert reamer.edge_axis_radius == pytest.approx(22.5e-3 + 0.4e-3 - 0.25e-3)
    points = reamer.tooth_points(samples=5)
    assert points.shape == (56, 5, 3)
    np.testing.assert_allclose(np.linalg.norm(points, axis=-1), reamer.edge_axis_radius)
    assert np.all(points[..., 2] >= -1e-15)  # teeth on the cutting dome z ≥ 0


def test_mass_of_the_solid_and_hollow_head(reamer):
    radius = 22.5e-3
    assert reamer.mass_kg == pytest.approx(7800 * 2 * math.pi / 3 * radius**3)
    assert reamer.mass_kg == pytest.approx(0.186, abs=1e-3)
    assert reamer.axial_inertia_kg_m2 == pytest.approx(0.4 * reamer.mass_kg * radius**2)
    hollow = build_reamer(ReamerConfig(wall_thickness_mm=2.0))
    inner = radius - 2e-3
    assert hollow.mass_kg == pytest.approx(7800 * 2 * math.pi / 3 * (radius**3 - inner**3))
    assert hollow.mass_kg < reamer.mass_kg


@pytest.mark.parametrize("inclination", [0, 15, 30, 45, 90])
@pytest.mark.parametrize("anteversion", [0, 45, 90, 180, 300])
@pytest.mark.parametrize("spin", [0.0, 1.3])
def test_frame_rotation_maps_z_to_axis(inclination, anteversion, spin):
    axis = np.array(Orientation(inclination_deg=inclination, anteversion_deg=anteversion).reamer_axis)
    rotation = frame_rotation(axis, spin)
    np.testing.assert_allclose(rotation @ [0, 0, 1], axis, atol=1e-12)
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)


def test_frame_rotation_for_axes_along_x_and_unnormalised():
    for axis in ([1, 0, 0], [-1, 0, 0], [0, 0, -5], [3, 4, 0]):
        rotation = frame_rotation(np.array(axis, dtype=float), 0.7)
        unit = np.array(axis) / np.linalg.norm(axis)
        np.testing.assert_allclose(rotation[:, 2], unit, atol=1e-12)
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)


def test_spin_turns_about_the_axis():
    axis = np.array([0.3, -0.2, -0.9])
    base, spun = frame_rotation(axis, 0.0), frame_rotation(axis, math.pi / 2)
    np.testing.assert_allclose(spun[:, 0], base[:, 1], atol=1e-12)
    np.testing.assert_allclose(spun[:, 2], base[:, 2], atol=1e-12)
