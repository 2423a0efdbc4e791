"""The static graph of the learned simulator [7.3.1]: one node per tet, edges between face-sharing tets.

Built once from the mesh (the topology never changes [7.3.1]; a removed element keeps its node
and only its features say it is gone). Per frame only the *region* near the reamer is looked at:
the cutting front (active elements on the free surface within the teeth's reach plus a margin of
the reamer centre, grown a face-hop or two into the bone), plus a halo of face-hops around it so
that message passing at the region's border sees the same kind of neighbourhood in training and
in use. Finding it costs one pass of gathers over the neighbour table; the network, by far the
dearest part, only sees the region.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from thrsim.geometry.mesh import INNER, TetMesh
from thrsim.geometry.tet_metrics import TET_FACES


@dataclass(frozen=True)
class Subgraph:
    """A region of the static graph: ``nodes`` (global ids, region first, then the halo).

    ``senders``/``receivers`` are local indices (both directions of every face adjacency with
    both ends in the subgraph); only the first ``n_region`` nodes are updated.
    """

    nodes: np.ndarray
    n_region: int
    senders: np.ndarray
    receivers: np.ndarray

    @property
    def region(self) -> np.ndarray:
        return self.nodes[: self.n_region]


def mesh_digest(mesh: TetMesh) -> str:
    """SHA-256 of the node coordinates and connectivity: a model belongs to exactly one mesh."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(mesh.nodes, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(mesh.tets, dtype=np.int32).tobytes())
    return digest.hexdigest()


class StaticGraph:
    """Centroids, volumes and the face-neighbour table of a mesh, plus region queries."""

    def __init__(self, mesh: TetMesh):
        self.mesh = mesh
        self.n_nodes = mesh.n_tets
        self.centroids = np.ascontiguousarray(mesh.centroids, dtype=np.float64)
        self.volumes = np.abs(mesh.volumes)
        self.neighbours = mesh.adjacency.neighbours
        pairs = mesh.adjacency.pairs
        self.senders = np.concatenate([pairs[:, 0], pairs[:, 1]])
        self.receivers = np.concatenate([pairs[:, 1], pairs[:, 0]])
        # distance of each centroid from the acetabular centre: where it sits across the shell
        self.radius = np.linalg.norm(self.centroids, axis=1)
        self.digest = mesh_digest(mesh)
        self._local = np.full(self.n_nodes, -1, dtype=np.int64)
        self._inner_faces = _inner_face_table(mesh)
        self._inner_tet = self._inner_faces.any(axis=1)
        self._inner_tet_ids = np.flatnonzero(self._inner_tet)
        self._face_centres = mesh.nodes[mesh.tets][:, TET_FACES].mean(axis=2)  # (E, 4 faces, 3)

    @property
    def n_edges(self) -> int:
        return int(len(self.senders))

    def exposed(self, active: np.ndarray) -> np.ndarray:
        """Active elements on the bone's free surface: a removed neighbour, or a face on the articular side."""
        table = self.neighbours
        removed_neighbour = ((table >= 0) & ~active[np.maximum(table, 0)]).any(axis=1)
        return active & (removed_neighbour | self._inner_tet)

    def open_faces(self, active: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Per element of ``ids``: how many of its four faces have no active tet behind them."""
        table = self.neighbours[ids]
        return ((table < 0) | ~active[np.maximum(table, 0)]).sum(axis=1)

    def region(self, active: np.ndarray, centre: np.ndarray, reach_m: float, hops: int) -> np.ndarray:
        """Sorted ids of the elements that can change this frame.

        The cutting front: exposed elements whose centroid lies within ``reach_m`` of the reamer
        centre, grown ``hops`` face-hops into the active bone (a frame can remove more than one
        layer). The reamer nearly conforms to the cavity, so a plain ball around it would hold
        most of the bone; the front is a thin sheet of it.
        """
        active = np.asarray(active, dtype=bool)
        # the exposed elements, gathered from the removed ones and the articular layer only
        # (the same set as `exposed`, without a pass over every element's neighbours)
        behind = self.neighbours[np.flatnonzero(~active)].ravel()
        candidates = np.concatenate([self._inner_tet_ids, behind[behind >= 0]])
        front = np.unique(candidates[active[candidates]])
        close = front[np.einsum("ij,ij->i", d := self.centroids[front] - centre, d) < reach_m * reach_m]
        local = self._local
        local[close] = 0
        frontier, parts = close, [close]
        for _ in range(hops):
            around = self.neighbours[frontier].ravel()
            around = around[around >= 0]
            around = np.unique(around[(local[around] < 0) & active[around]])
            if len(around) == 0:
                break
            local[around] = 0
            parts.append(around)
            frontier = around
        region = np.sort(np.concatenate(parts))
        local[region] = -1
        return region

    def subgraph(self, region: np.ndarray, halo_hops: int) -> Subgraph:
        """The region plus ``halo_hops`` face-hops around it, with the edges among them."""
        local = self._local
        nodes = [np.asarray(region, dtype=np.int64)]
        local[nodes[0]] = 0
        frontier = nodes[0]
        for _ in range(halo_hops):
            around = self.neighbours[frontier].ravel()
            around = around[around >= 0]
            around = np.unique(around[local[around] < 0])
            if len(around) == 0:
                break
            local[around] = 0
            nodes.append(around)
            frontier = around
        all_nodes = np.concatenate(nodes)
        local[all_nodes] = np.arange(len(all_nodes))
        table = self.neighbours[all_nodes]
        mapped = np.where(table >= 0, local[np.maximum(table, 0)], -1)
        present = mapped >= 0
        receivers = np.repeat(np.arange(len(all_nodes)), 4).reshape(-1, 4)[present]
        senders = mapped[present]
        local[all_nodes] = -1
        return Subgraph(nodes=all_nodes, n_region=len(nodes[0]), senders=senders, receivers=receivers)

    def whole(self) -> Subgraph:
        """The whole mesh as one subgraph (every node updated), as the thesis's Algorithm 1 runs."""
        return Subgraph(nodes=np.arange(self.n_nodes), n_region=self.n_nodes, senders=self.senders, receivers=self.receivers)

    def reamed_surface(self, active: np.ndarray) -> np.ndarray:
        """Centroids of the faces of the cavity the reamer made, (S, 3) m.

        Those are the faces of removed tets that face remaining bone (the cavity wall) or lie on
        the patch's outer or side boundary (where the cut went through the shell). The original
        articular faces are not part of it: where they remain they were never reamed, and a
        patch reamed through leaves its outer faces as the cavity, not fragments of bone.
        """
        removed = ~np.asarray(active, dtype=bool)
        table = self.neighbours
        facing_bone = (table >= 0) & ~removed[np.maximum(table, 0)]
        through = (table < 0) & ~self._inner_faces
        tet, face = np.nonzero(removed[:, None] & (facing_bone | through))
        return self._face_centres[tet, face]


def _inner_face_table(mesh: TetMesh) -> np.ndarray:
    """(E, 4) bool: the tet's local face lies on the articular boundary (all three nodes in ``inner``)."""
    table = np.zeros((mesh.n_tets, 4), dtype=bool)
    inner = mesh.node_sets.get(INNER)
    if inner is None or len(inner) == 0:
        return table
    on_inner = np.zeros(mesh.n_nodes, dtype=bool)
    on_inner[inner] = True
    adjacency = mesh.adjacency
    owner, local_face = adjacency.boundary_owner, adjacency.boundary_local_face
    face_nodes = np.asarray(mesh.tets)[owner[:, None], TET_FACES[local_face]]
    table[owner, local_face] = on_inner[face_nodes].all(axis=1)
    return table
