"""The static graph of the learned simulator [7.3.1]: one node per tet, edges between face-sharing tets.

Built once from the mesh (the topology never changes [7.3.1]; a removed element keeps its node
and only its features say it is gone). Per frame only the *region* near the reamer is looked at:
the cutting front (active elements on the free surface within the teeth's reach plus a margin of
the reamer centre, grown a face-hop or two into the bone), plus a halo of face-hops around it so
that message passing at the region's border sees the same kind of neighbourhood in training and
in use. Finding it costs one compiled pass over the neighbour table (Numba: a few hundred
microseconds of NumPy gathers and sorts become tens, and the interactive step pays it every
frame); the network, by far the dearest part, only sees the region.
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass

import numpy as np
from numba import njit

from thrsim.cache import use_numba_cache
from thrsim.geometry.mesh import REAMED_FACES, SIDE, WINDOW_SIDE, TetMesh
from thrsim.geometry.tet_metrics import TET_FACES

use_numba_cache()  # before the first kernel: Numba reads the cache folder then


#: the volume of a regular tetrahedron of the solver's 0.45 mm edge (m³): a contact weight of 1
REFERENCE_TET_VOLUME_M3 = (0.45e-3) ** 3 / (6.0 * 2.0**0.5)


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
        self.corners = np.ascontiguousarray(mesh.nodes[mesh.tets], dtype=np.float64)  # (E, 4, 3)
        self.volumes = np.abs(mesh.volumes)
        # each element's share of a contact area, (V / V_ref)^(2/3): summed over the elements in
        # contact it grows with the area touched, not their number, so a reaction law learned on
        # one mesh holds on a coarser or finer one
        self.contact_weight = ((self.volumes / REFERENCE_TET_VOLUME_M3) ** (2.0 / 3.0)).astype(np.float32)
        self.neighbours = mesh.adjacency.neighbours
        pairs = mesh.adjacency.pairs
        self.senders = np.concatenate([pairs[:, 0], pairs[:, 1]])
        self.receivers = np.concatenate([pairs[:, 1], pairs[:, 0]])
        # distance of each centroid from the acetabular centre: where it sits across the shell
        self.radius = np.linalg.norm(self.centroids, axis=1)
        self.digest = mesh_digest(mesh)
        self._scratch = threading.local()  # see _scratch_arrays
        self._inner_faces = _inner_face_table(mesh)
        self._inner_tet = self._inner_faces.any(axis=1)
        self._face_centres = mesh.nodes[mesh.tets][:, TET_FACES].mean(axis=2)  # (E, 4 faces, 3)
        # elements on what the solver holds (its fixed nodes) or rests on its elastic foundation (a
        # patch's sides, a window's cut sides): bone still face-connected to one of them stays
        held = np.zeros(mesh.n_nodes, dtype=bool)
        for ids in (mesh.fixed_nodes, mesh.node_sets.get(SIDE, ()), mesh.node_sets.get(WINDOW_SIDE, ())):
            held[np.asarray(ids, dtype=np.int64)] = True
        self.anchored = held[mesh.tets].any(axis=1)

    def _scratch_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """This thread's scratch: local ids (of ``subgraph``, left all -1) and marks (of ``region``, left
        all False). A model's graph is shared by every session of a server, and a session starting on
        one thread while another steps on a second must not write the same scratch (that crashed)."""
        scratch = self._scratch
        if not hasattr(scratch, "local"):
            scratch.local = np.full(self.n_nodes, -1, dtype=np.int64)
            scratch.mark = np.zeros(self.n_nodes, dtype=np.bool_)
        return scratch.local, scratch.mark

    def chips(self, active: np.ndarray) -> np.ndarray:
        """Active elements cut off from the anchored bone (bool per element): the solver deletes
        them at the end of each frame, as debris."""
        return unanchored_elements(self.neighbours, np.ascontiguousarray(active, dtype=np.bool_), self.anchored)

    @property
    def n_edges(self) -> int:
        return int(len(self.senders))

    def exposed(self, active: np.ndarray) -> np.ndarray:
        """Active elements on the bone's free surface: a removed neighbour, or a face on the articular side."""
        return _exposed_elements(self.neighbours, self._inner_tet, np.ascontiguousarray(active, dtype=np.bool_))

    def region(self, active: np.ndarray, centre: np.ndarray, reach_m: float, hops: int) -> np.ndarray:
        """Sorted ids of the elements that can change this frame.

        The cutting front: exposed elements whose centroid lies within ``reach_m`` of the reamer
        centre, grown ``hops`` face-hops into the active bone (a frame can remove more than one
        layer). The reamer nearly conforms to the cavity, so a plain ball around it would hold
        most of the bone; the front is a thin sheet of it.
        """
        active = np.ascontiguousarray(active, dtype=np.bool_)
        centre = np.ascontiguousarray(centre, dtype=np.float64)
        return _cutting_front(
            self.neighbours, self._inner_tet, active, self.centroids, centre, reach_m * reach_m, hops, self._scratch_arrays()[1]
        )

    def front_entry_m(self, active: np.ndarray, centre: np.ndarray, axis: np.ndarray, reach_m: float) -> float:
        """Smallest advance s ≥ 0 along ``axis`` after which an exposed active element's centroid lies
        within ``reach_m`` of the centre c + s·D, as :meth:`region` looks for the cutting front (0 when
        one already does, inf when none ever will)."""
        active = np.ascontiguousarray(active, dtype=np.bool_)
        return float(
            _front_entry(
                self.neighbours,
                self._inner_tet,
                active,
                self.centroids,
                np.ascontiguousarray(centre, dtype=np.float64),
                np.ascontiguousarray(axis, dtype=np.float64),
                reach_m,
            )
        )

    def subgraph(self, region: np.ndarray, halo_hops: int) -> Subgraph:
        """The region plus ``halo_hops`` face-hops around it, with the edges among them."""
        local = self._scratch_arrays()[0]
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
    """(E, 4) bool: the tet's local face lies on the face the reamer meets first (all three nodes in
    the patch's ``inner`` or the socket's ``articular`` set)."""
    table = np.zeros((mesh.n_tets, 4), dtype=bool)
    inner = next((mesh.node_sets[name] for name in REAMED_FACES if name in mesh.node_sets), None)
    if inner is None or len(inner) == 0:
        return table
    on_inner = np.zeros(mesh.n_nodes, dtype=bool)
    on_inner[inner] = True
    adjacency = mesh.adjacency
    owner, local_face = adjacency.boundary_owner, adjacency.boundary_local_face
    face_nodes = np.asarray(mesh.tets)[owner[:, None], TET_FACES[local_face]]
    table[owner, local_face] = on_inner[face_nodes].all(axis=1)
    return table


@njit(cache=True)
def _exposed(neighbours, inner_tet, active, element):
    """An active element on the bone's free surface (see :meth:`StaticGraph.exposed`)."""
    if not active[element]:
        return False
    if inner_tet[element]:
        return True
    for k in range(4):
        neighbour = neighbours[element, k]
        if neighbour >= 0 and not active[neighbour]:
            return True
    return False


@njit(cache=True)
def _exposed_elements(neighbours, inner_tet, active):
    """:func:`_exposed` of every element (bool per element)."""
    out = np.zeros(len(active), dtype=np.bool_)
    for element in range(len(active)):
        out[element] = _exposed(neighbours, inner_tet, active, element)
    return out


@njit(cache=True)
def _front_entry(neighbours, inner_tet, active, centroids, centre, axis, reach):
    """Smallest advance along ``axis`` after which an exposed element's centroid is within ``reach``
    (see :meth:`StaticGraph.front_entry_m`): a point p enters the ball at s = a − √(a² − |r|² + ρ²),
    r = p − c, a = r·D, while the far crossing a + √(…) is still ahead."""
    best = np.inf
    for element in range(len(active)):
        rx = centroids[element, 0] - centre[0]
        ry = centroids[element, 1] - centre[1]
        rz = centroids[element, 2] - centre[2]
        along = rx * axis[0] + ry * axis[1] + rz * axis[2]
        disc = along * along - (rx * rx + ry * ry + rz * rz) + reach * reach
        if disc < 0.0:
            continue
        root = np.sqrt(disc)
        if along + root < 0.0 or along - root >= best:
            continue
        if _exposed(neighbours, inner_tet, active, element):
            best = max(0.0, along - root)
    return best


@njit(cache=True)
def _cutting_front(neighbours, inner_tet, active, centroids, centre, reach_squared, hops, mark):
    """Sorted ids of the exposed active elements within reach, grown ``hops`` face-hops into the
    active bone (see :meth:`StaticGraph.region`); ``mark`` is all False on entry and on exit."""
    ids = np.empty(len(active), dtype=np.int64)
    count = 0
    for element in range(len(active)):
        dx = centroids[element, 0] - centre[0]
        dy = centroids[element, 1] - centre[1]
        dz = centroids[element, 2] - centre[2]
        # the distance first: it rules out most of the mesh at the cost of reading one centroid
        if dx * dx + dy * dy + dz * dz < reach_squared and _exposed(neighbours, inner_tet, active, element):
            mark[element] = True
            ids[count] = element
            count += 1
    start, end = 0, count
    for _ in range(hops):
        for i in range(start, end):
            for k in range(4):
                neighbour = neighbours[ids[i], k]
                if neighbour >= 0 and active[neighbour] and not mark[neighbour]:
                    mark[neighbour] = True
                    ids[count] = neighbour
                    count += 1
        if count == end:
            break
        start, end = end, count
    region = np.sort(ids[:count])
    for element in region:
        mark[element] = False
    return region


@njit(cache=True)
def attached_nodes(tets, active, n_nodes):
    """Mesh nodes of at least one active element (bool per node)."""
    attached = np.zeros(n_nodes, dtype=np.bool_)
    for element in range(len(tets)):
        if active[element]:
            for k in range(4):
                attached[tets[element, k]] = True
    return attached


@njit(cache=True)
def unanchored_elements(neighbours, active, anchored):
    """Active elements not face-connected, through active elements, to an active ``anchored`` one
    (bool per element): the chips the solver deletes at the end of each frame."""
    n = len(active)
    reached = np.zeros(n, dtype=np.bool_)
    queue = np.empty(n, dtype=np.int64)
    end = 0
    for element in range(n):
        if active[element] and anchored[element]:
            reached[element] = True
            queue[end] = element
            end += 1
    head = 0
    while head < end:
        element = queue[head]
        head += 1
        for k in range(neighbours.shape[1]):
            other = neighbours[element, k]
            if other >= 0 and active[other] and not reached[other]:
                reached[other] = True
                queue[end] = other
                end += 1
    return active & ~reached
