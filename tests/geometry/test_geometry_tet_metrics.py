"""Volumes, centroids, minimum altitudes and the quality report against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.tet_metrics import (
    SLIVER_QUALITY,
    centroids,
    face_areas,
    minimum_altitudes,
    quality_report,
    signed_volumes,
    volume_quality,
)

A, B, C = 2.0, 3.0, 4.0
# right-corner tet with legs a, b, c along x, y, z
CORNER = np.array([[0, 0, 0], [A, 0, 0], [0, B, 0], [0, 0, C]], dtype=float)
ONE = np.array([[0, 1, 2, 3]])
REGULAR = np.array([[1, 1, 1], [-1, 1, -1], [1, -1, -1], [-1, -1, 1]], dtype=float)  # edge 2√2


def test_corner_tet_closed_forms():
    assert signed_volumes(CORNER, ONE)[0] == pytest.approx(A * B * C / 6)
    np.testing.assert_allclose(centroids(CORNER, ONE)[0], [A / 4, B / 4, C / 4])
    # altitudes: a, b, c from the three leg tips; from the right corner to the slanted face
    slanted = 1.0 / math.sqrt(1 / A**2 + 1 / B**2 + 1 / C**2)
    assert minimum_altitudes(CORNER, ONE)[0] == pytest.approx(min(A, B, C, slanted))
    areas = face_areas(CORNER, ONE)[0]
    # face i is opposite vertex i: slanted face, then the y-z, x-z, x-y right triangles
    assert areas[1:] == pytest.approx([B * C / 2, A * C / 2, A * B / 2])
    assert areas[0] == pytest.approx(3 * A * B * C / 6 / slanted)


def test_regular_tet_quality_and_altitude():
    edge = 2 * math.sqrt(2)
    assert signed_volumes(REGULAR, ONE)[0] == pytest.approx(edge**3 / (6 * math.sqrt(2)))
    assert volume_quality(REGULAR, ONE)[0] == pytest.approx(1.0)
    assert minimum_altitudes(REGULAR, ONE)[0] == pytest.approx(edge * math.sqrt(2 / 3))
    np.testing.assert_allclose(centroids(REGULAR, ONE)[0], 0.0, atol=1e-15)


def test_swapping_two_nodes_inverts():
    swapped = ONE[:, [0, 2, 1, 3]]
    assert signed_volumes(CORNER, swapped)[0] == pytest.approx(-A * B * C / 6)
    assert minimum_altitudes(CORNER, swapped)[0] == pytest.approx(minimum_altitudes(CORNER, ONE)[0])


def test_quality_report_counts_hand_made_tets():
    nodes = np.vstack(
        [
            REGULAR,  # 0-3 regular
            [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]],  # 4-7 four coplanar points
            [[0, 0, 0], [1, 1, 0], [1, 0, 0.01], [0, 1, 0.01]],  # 8-11 flat sliver
        ]
    )
    tets = np.array(
        [
            [0, 1, 2, 3],  # good
            [0, 2, 1, 3],  # inverted
            [4, 5, 6, 7],  # degenerate (zero volume)
            [8, 10, 9, 11],  # sliver, positive
            [8, 9, 10, 11],  # the same sliver inverted: counted as inverted, not as a sliver
        ]
    )
    assert signed_volumes(nodes, tets[3:4])[0] > 0
    assert 0 < volume_quality(nodes, tets[3:4])[0] < SLIVER_QUALITY
    report = quality_report(nodes, tets)
    assert (report.elements, report.inverted, report.degenerate, report.slivers) == (5, 2, 1, 1)
    assert not report.valid
    assert report.min_quality == pytest.approx(-1.0)
    assert report.as_dict()["slivers"] == 1

    good = quality_report(nodes, tets[:1])
    assert good.valid and good.slivers == 0 and good.min_quality == pytest.approx(1.0)


def test_quality_report_is_scale_free():
    for scale in (1e-3, 1.0, 1e3):
        report = quality_report(REGULAR * scale, ONE)
        assert report.degenerate == 0 and report.inverted == 0
        assert report.min_altitude == pytest.approx(scale * 2 * math.sqrt(2) * math.sqrt(2 / 3))


@pytest.mark.parametrize(
    ("nodes", "tets", "problem"),
    [
        (CORNER, ONE[:, [0, 2, 1, 3]], "inverted"),
        (np.vstack([CORNER[:3], [1.0, 1.0, 0.0]]), ONE, "zero-volume"),
        (CORNER, np.array([[0, 1, 1, 3]]), "repeats a node"),
        (np.where(np.arange(12).reshape(4, 3) == 4, np.nan, CORNER), ONE, "NaN"),
        (CORNER, np.array([[0, 1, 2, 7]]), "do not exist"),
        (CORNER, np.zeros((0, 4), dtype=int), "no tetrahedra"),
    ],
)
def test_validate_refuses_bad_meshes(nodes, tets, problem):
    with pytest.raises(ThrsimInputError, match=problem) as error:
        TetMesh(nodes=nodes, tets=tets).validate(source="hand.inp")
    assert str(error.value).startswith("hand.inp: ")
    assert "\n" not in str(error.value)


def test_mesh_properties(two_tets):
    nodes, tets = two_tets
    mesh = TetMesh(nodes=nodes, tets=tets, node_sets={"base": [2, 0, 1, 0]}, fixed_nodes=[3, 0])
    assert mesh.tets.dtype == np.int32 and mesh.nodes.dtype == np.float64
    np.testing.assert_array_equal(mesh.node_sets["base"], [0, 1, 2])
    np.testing.assert_array_equal(mesh.fixed_nodes, [0, 3])
    report = mesh.validate()
    assert report.valid
    summary = mesh.summary()
    assert (summary["elements"], summary["nodes"], summary["edges"], summary["boundary_faces"]) == (2, 5, 1, 6)
    assert summary["volume_mm3"] == pytest.approx((1 / 6 + 2 / 6) * 1e9)
