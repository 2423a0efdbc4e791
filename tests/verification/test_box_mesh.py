"""Structured box meshes: volume, orientation, conformity, node sets."""

from __future__ import annotations

import numpy as np
import pytest

from thrsim.geometry.box_mesh import box_mesh


@pytest.mark.parametrize("scheme", ["six", "five"])
@pytest.mark.parametrize("jitter", [0.0, 0.3])
def test_box_mesh_is_a_valid_conforming_tiling(scheme: str, jitter: float) -> None:
    mesh = box_mesh((3, 2, 4), (3e-3, 2e-3, 4e-3), origin=(1e-3, 0.0, -1e-3), scheme=scheme, jitter=jitter, seed=2)
    mesh.validate()  # positive volumes, manifold faces
    assert mesh.n_tets == 24 * (6 if scheme == "six" else 5)
    assert np.isclose(mesh.volumes.sum(), 24e-9, rtol=1e-12)
    # conforming: every boundary face lies on the box surface (no hanging interior faces)
    faces = mesh.adjacency.boundary_faces
    assert len(faces) == 2 * (3 * 2 + 2 * 4 + 3 * 4) * 2
    assert set(mesh.node_sets) >= {"xmin", "xmax", "ymin", "ymax", "zmin", "zmax", "boundary", "interior"}
    assert len(mesh.node_sets["interior"]) == 2 * 1 * 3
    assert np.allclose(mesh.nodes[mesh.node_sets["xmax"], 0], 4e-3)


def test_fixed_node_set_and_bad_input() -> None:
    mesh = box_mesh((1, 1, 2), (1.0, 1.0, 2.0), fixed="zmin")
    assert np.array_equal(mesh.fixed_nodes, mesh.node_sets["zmin"])
    with pytest.raises(ValueError):
        box_mesh((0, 1, 1), (1.0, 1.0, 1.0))
    with pytest.raises(ValueError):
        box_mesh((1, 1, 1), (1.0, 1.0, 1.0), scheme="seven")
