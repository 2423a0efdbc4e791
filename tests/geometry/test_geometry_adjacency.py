"""Face adjacency of tets and boundary-surface extraction."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_helpers import orient
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import Delaunay

from thrsim.errors import ThrsimInputError
from thrsim.geometry.adjacency import exposed_faces, face_adjacency
from thrsim.geometry.tet_metrics import TET_FACES, centroids, signed_volumes


def face_normals(nodes, faces):
    p = nodes[faces]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def assert_outward(nodes, tets, adjacency):
    """Every boundary face's right-hand normal points away from its owner tet's centroid."""
    faces = adjacency.boundary_faces
    normal = face_normals(nodes, faces)
    away = nodes[faces].mean(axis=1) - centroids(nodes, tets)[adjacency.boundary_owner]
    assert np.all(np.einsum("ij,ij->i", normal, away) > 0)
    # each boundary face is the owner's local face, opposite the named vertex
    owner_faces = tets[adjacency.boundary_owner[:, None], TET_FACES[adjacency.boundary_local_face]]
    np.testing.assert_array_equal(owner_faces, faces)


def test_two_tets_share_one_face(two_tets):
    nodes, tets = two_tets
    adj = face_adjacency(tets)
    np.testing.assert_array_equal(adj.pairs, [[0, 1]])
    np.testing.assert_array_equal(adj.neighbours, [[1, -1, -1, -1], [-1, -1, -1, 0]])
    assert len(adj.boundary_faces) == 6
    assert_outward(nodes, tets, adj)
    np.testing.assert_array_equal(adj.directed_edges, [[0, 1], [1, 0]])


def test_five_tet_cube(cube):
    nodes, tets = cube
    assert np.all(signed_volumes(nodes, tets) > 0)
    adj = face_adjacency(tets)
    # the central tet 0 touches every corner tet; corners touch only the centre (they share edges)
    np.testing.assert_array_equal(adj.pairs, [[0, 1], [0, 2], [0, 3], [0, 4]])
    assert sorted(adj.neighbours[0]) == [1, 2, 3, 4]
    for corner in range(1, 5):
        row = adj.neighbours[corner]
        assert sorted(row) == [-1, -1, -1, 0]
        # the shared face is the one opposite the cube corner (the corner tet's first node)
        assert row[0] == 0
    # 6 cube faces × 2 triangles, all lying on the cube's faces
    assert len(adj.boundary_faces) == 12
    on_cube_face = np.any(
        np.all(np.isin(nodes[adj.boundary_faces], (0.0, 1.0)), axis=1) & (np.ptp(nodes[adj.boundary_faces], axis=1) == 0), axis=1
    )
    assert on_cube_face.all()
    assert_outward(nodes, tets, adj)
    assert adj.directed_edges.shape == (2, 8)


def test_non_manifold_face_is_refused():
    tets = np.array([[0, 1, 2, 3], [0, 1, 2, 4], [0, 2, 1, 5]])
    with pytest.raises(ThrsimInputError, match="non-manifold"):
        face_adjacency(tets)


def test_exposed_faces_after_removing_tets(cube):
    nodes, tets = cube
    adj = face_adjacency(tets)
    everything = np.ones(5, dtype=bool)
    owner, local = exposed_faces(adj, everything)
    assert len(owner) == 12
    assert set(zip(owner.tolist(), local.tolist(), strict=True)) == set(
        zip(adj.boundary_owner.tolist(), adj.boundary_local_face.tolist(), strict=True)
    )

    no_centre = everything.copy()
    no_centre[0] = False
    owner, local = exposed_faces(adj, no_centre)
    assert len(owner) == 16 and 0 not in owner

    no_corner = everything.copy()
    no_corner[1] = False
    owner, local = exposed_faces(adj, no_corner)
    assert len(owner) == 10
    # the centre now shows the face it shared with the removed corner
    assert (0, int(np.flatnonzero(adj.neighbours[0] == 1)[0])) in set(zip(owner.tolist(), local.tolist(), strict=True))

    assert len(exposed_faces(adj, np.zeros(5, dtype=bool))[0]) == 0


def test_exposed_faces_match_surface_of_remaining_mesh(coarse_patch):
    mesh = coarse_patch
    rng = np.random.default_rng(3)
    active = rng.random(mesh.n_tets) > 0.3
    owner, local = exposed_faces(mesh.adjacency, active)
    faces = mesh.tets[owner[:, None], TET_FACES[local]]
    sub = face_adjacency(mesh.tets[active])
    key = lambda f: {tuple(sorted(row)) for row in f.tolist()}  # noqa: E731
    assert key(faces) == key(sub.boundary_faces)
    assert len(faces) == len(sub.boundary_faces)


@settings(max_examples=40, deadline=None)
@given(
    n_points=st.integers(min_value=5, max_value=60),
    keep=st.floats(min_value=0.2, max_value=1.0),
    seed=st.integers(min_value=0, max_value=2**31 - 1),
)
def test_adjacency_properties_on_random_meshes(n_points, keep, seed):
    rng = np.random.default_rng(seed)
    nodes = rng.random((n_points, 3))
    tets = Delaunay(nodes).simplices
    tets = tets[rng.random(len(tets)) < keep]
    if len(tets) == 0:
        tets = Delaunay(nodes).simplices[:1]
    tets = orient(nodes, rng.permuted(tets, axis=1))
    adj = face_adjacency(tets)
    n = len(tets)

    # pairs are i < j, sorted and unique
    assert np.all(adj.pairs[:, 0] < adj.pairs[:, 1])
    assert len(np.unique(adj.pairs, axis=0)) == len(adj.pairs)
    # symmetric neighbour table: j is across a face of i exactly when i is across a face of j
    for i, j in adj.pairs:
        assert list(adj.neighbours[i]).count(j) == 1 and list(adj.neighbours[j]).count(i) == 1
    links = {(i, int(j)) for i in range(n) for j in adj.neighbours[i] if j >= 0}
    assert links == {(int(i), int(j)) for i, j in adj.pairs} | {(int(j), int(i)) for i, j in adj.pairs}

    # brute force: each interior face appears once as a pair, every other face is boundary
    counts: dict[tuple, list[int]] = {}
    for t, tet in enumerate(tets):
        for face in TET_FACES:
            counts.setdefault(tuple(sorted(tet[face])), []).append(t)
    interior = {tuple(sorted(owners)) for owners in counts.values() if len(owners) == 2}
    assert interior == {(int(i), int(j)) for i, j in adj.pairs}
    assert len(adj.boundary_faces) == sum(len(o) == 1 for o in counts.values())
    assert 2 * len(adj.pairs) + len(adj.boundary_faces) == 4 * n
    assert_outward(nodes, tets, adj)
