"""Face adjacency of tetrahedra and boundary-surface extraction, built once, vectorised.

Two tets are neighbours when they share a face (three nodes). This is the graph topology of
the learned simulator (static: built once per mesh, never rebuilt per frame) and the surface the solver
and renderers draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thrsim.errors import ThrsimInputError
from thrsim.geometry.tet_metrics import TET_FACES


@dataclass(frozen=True)
class FaceAdjacency:
    """Static face-adjacency structure of a tet mesh.

    ``pairs``: (P, 2) undirected neighbour pairs, i < j. ``neighbours``: (E, 4) the tet across
    local face i (opposite vertex i), −1 on the boundary. ``boundary_faces``: (B, 3) node
    triples of faces with one tet, oriented outward; ``boundary_owner``: (B,) their tet;
    ``boundary_local_face``: (B,) the face's local index in that tet.
    """

    pairs: np.ndarray
    neighbours: np.ndarray
    boundary_faces: np.ndarray
    boundary_owner: np.ndarray
    boundary_local_face: np.ndarray

    @property
    def directed_edges(self) -> np.ndarray:
        """(2, 2P) sender/receiver index array with both directions (graph-network layout)."""
        return np.concatenate([self.pairs.T, self.pairs[:, ::-1].T], axis=1)


def face_adjacency(tets: np.ndarray) -> FaceAdjacency:
    """Match every tet face with its twin by sorting node triples (O(E log E), no Python loop)."""
    tets = np.asarray(tets, dtype=np.int64)
    n_tets = len(tets)
    oriented = tets[:, TET_FACES].reshape(-1, 3)  # (4E, 3), outward for positive tets
    keys = np.sort(oriented, axis=1)
    order = np.lexsort((keys[:, 2], keys[:, 1], keys[:, 0]))
    sorted_keys = keys[order]
    same_as_next = np.all(sorted_keys[1:] == sorted_keys[:-1], axis=1)
    if np.any(same_as_next[1:] & same_as_next[:-1]):
        raise ThrsimInputError("non-manifold mesh: a face is shared by more than two tetrahedra")

    first = order[:-1][same_as_next]
    second = order[1:][same_as_next]
    tet_a, face_a = np.divmod(first, 4)
    tet_b, face_b = np.divmod(second, 4)
    neighbours = np.full((n_tets, 4), -1, dtype=np.int64)
    neighbours[tet_a, face_a] = tet_b
    neighbours[tet_b, face_b] = tet_a
    pairs = np.sort(np.stack([tet_a, tet_b], axis=1), axis=1)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]

    boundary = np.flatnonzero(neighbours.reshape(-1) < 0)
    owner, local_face = np.divmod(boundary, 4)
    return FaceAdjacency(
        pairs=pairs.astype(np.int64),
        neighbours=neighbours,
        boundary_faces=oriented[boundary],
        boundary_owner=owner,
        boundary_local_face=local_face,
    )


def exposed_faces(adjacency: FaceAdjacency, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces of active tets whose neighbour is missing or removed: the visible bone surface.

    Returns (tet index, local face index) arrays; cheap enough to call per frame because it
    only reads the precomputed neighbour table.
    """
    active = np.asarray(active, dtype=bool)
    neighbour_active = np.where(adjacency.neighbours >= 0, active[np.maximum(adjacency.neighbours, 0)], False)
    visible = active[:, None] & ~neighbour_active
    elements, faces = np.nonzero(visible)
    return elements, faces
