"""The pelvis's bone surface the trainer pages draw: closed and outward, a few thousand triangles,
through the landmarks the trainers use, its socket open along the native opening, both hips alike."""

from __future__ import annotations

import numpy as np
import pytest

from thrsim.nav.pelvis import ACETABULUM_CENTRE_RIGHT, native_axis_right, synthetic_pelvis_landmarks
from thrsim.nav.pelvis_surface import PAYLOAD_MAGIC, SOCKET_RADIUS_MM, pelvis_surface, surface_payload


@pytest.fixture(scope="module")
def surface():
    return pelvis_surface()


def _edges(triangles: np.ndarray) -> np.ndarray:
    return np.vstack([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])


def _ray_hits(surface, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Distances along the ray at which it crosses a triangle (Möller–Trumbore)."""
    a, b, c = (surface.vertices[surface.triangles[:, k]] for k in range(3))
    e1, e2 = b - a, c - a
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-15
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ direction) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    return t[ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)]


def _distance_to_surface(surface, point: np.ndarray) -> float:
    """Distance from a point to the triangles, each sampled on a barycentric grid (about 0.5 mm apart)."""
    near = np.any(np.linalg.norm(surface.vertices[surface.triangles] - point, axis=2) < 0.02, axis=1)  # facets are under 2 cm
    a, b, c = (surface.vertices[surface.triangles[near, k]] for k in range(3))
    if not len(a):
        return np.inf
    steps = 20
    weights = np.array([(i, j) for i in range(steps + 1) for j in range(steps + 1 - i)], dtype=float) / steps
    samples = a[:, None] + weights[None, :, :1] * (b - a)[:, None] + weights[None, :, 1:] * (c - a)[:, None]
    return float(np.min(np.linalg.norm(samples - point, axis=2)))


def test_the_surface_is_closed_outward_and_a_few_thousand_triangles(surface):
    assert 3_000 <= len(surface.triangles) <= 9_000
    edges = np.sort(_edges(surface.triangles), axis=1)
    _, shared = np.unique(edges, axis=0, return_counts=True)
    assert np.all(shared % 2 == 0) and np.mean(shared == 2) > 0.998  # closed; a few edges where two sheets touch
    # every directed edge has its reverse: the triangles turn one way, seen from outside
    directed = {tuple(e) for e in _edges(surface.triangles)}
    assert np.mean([(b, a) in directed for a, b in directed]) > 0.998
    v, t = surface.vertices, surface.triangles
    volume_cm3 = np.einsum("ij,ij->i", v[t[:, 0]], np.cross(v[t[:, 1]], v[t[:, 2]])).sum() / 6 * 1e6
    assert 400 < volume_cm3 < 1_200  # positive: the normals point out of the bone; a whole pelvis's size
    assert np.allclose(np.linalg.norm(surface.normals, axis=1), 1.0)
    # the smooth normals agree with the faces they surround (outward)
    face_normals = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    assert np.mean(np.einsum("ij,ij->i", face_normals, surface.normals[t].sum(axis=1)) > 0) > 0.99


@pytest.mark.parametrize("side", ["right", "left"])
def test_every_landmark_the_trainers_use_lies_on_the_bone(surface, side):
    for name, point in synthetic_pelvis_landmarks(side).items():
        assert _distance_to_surface(surface, point) < 3e-3, name  # within 3 mm: the probe touches bone there


def test_the_socket_is_open_along_the_native_opening_and_hemispherical(surface):
    centre, axis = ACETABULUM_CENTRE_RIGHT, native_axis_right()
    assert len(_ray_hits(surface, centre, axis)) == 0  # nothing between the socket and a camera looking into it
    for side in (1.0, -1.0):  # both hips
        mirror = np.array([side, 1.0, 1.0])
        hits = _ray_hits(surface, centre * mirror, -axis * mirror)  # into the floor
        assert abs(np.min(hits) * 1e3 - SOCKET_RADIUS_MM) < 1.5  # within its 8 mm facets' chords
        off_axis = np.cross(axis, [0.0, 0.0, 1.0])
        off_axis /= np.linalg.norm(off_axis)
        wall = _ray_hits(surface, centre * mirror, (-0.5 * axis + 0.866 * off_axis) * mirror)  # 60° from the pole
        assert abs(np.min(wall) * 1e3 - SOCKET_RADIUS_MM) < 1.5


def test_the_payload_carries_the_surface(surface):
    payload = surface_payload(surface)
    assert payload[:4] == PAYLOAD_MAGIC
    version, vertices, triangles = np.frombuffer(payload[4:16], dtype="<u4")
    assert version == 1 and (vertices, triangles) == (len(surface.vertices), len(surface.triangles))
    assert len(payload) == 16 + 24 * vertices + 12 * triangles
    positions = np.frombuffer(payload[16 : 16 + 12 * vertices], dtype="<f4").reshape(-1, 3)
    assert np.allclose(positions, surface.vertices, atol=1e-7)
    indices = np.frombuffer(payload[16 + 24 * vertices :], dtype="<u4").reshape(-1, 3)
    assert np.array_equal(indices, surface.triangles)
