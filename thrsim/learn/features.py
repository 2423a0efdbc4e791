"""Per-frame inputs of the learned simulator (the thesis's graph [7.3.1], plus what helps; see FeatureSettings).

Everything is computed on a :class:`~thrsim.learn.graph.Subgraph` only (the region near the
reamer and its halo), from arrays already in memory: a centroid table, α, the reamer centre,
axis and force. Several subgraphs are batched by concatenation with index offsets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from numba import njit

from thrsim.cache import use_numba_cache
from thrsim.learn.graph import REFERENCE_TET_VOLUME_M3, StaticGraph, Subgraph
from thrsim.learn.settings import FeatureSet, FeatureSettings

use_numba_cache()  # before the first kernel: Numba reads the cache folder then


#: what each node column holds, by feature set (before the corner and damage columns), in the
#: order the compiled kernels write them; "relative" is centroid − reamer centre
NODE_COLUMNS = {
    "full": (
        "relative_x", "relative_y", "relative_z", "axial", "radial", "teeth_distance", "cutting_speed",
        "cos_shell_normal", "socket_radius", "alpha", "active", "open_faces",
    ),
    "thesis": ("relative_x", "relative_y", "relative_z", "alpha"),
    "socket": ("axial", "radial", "teeth_distance", "cutting_speed", "cos_shell_normal", "alpha", "active", "open_faces", "log10_cutting_energy"),
}  # fmt: skip
#: the corner columns (``FeatureSettings.corners``): four sorted corner distances, the nearest at t − 1
CORNER_NAMES = ("corner_distance_0", "corner_distance_1", "corner_distance_2", "corner_distance_3", "nearest_corner_before")


def node_columns(features: FeatureSettings) -> tuple[str, ...]:
    """The names of a model's node inputs, in order."""
    return NODE_COLUMNS[features.feature_set] + CORNER_NAMES * int(features.corners) + ("damage",) * int(features.damage)


def reach_m(teeth_radius_m: float, features: FeatureSettings) -> float:
    """How far from the reamer centre the cutting front is looked for: the teeth's reach plus the margin."""
    return teeth_radius_m + features.reach_margin_mm * 1e-3


def select_subgraph(
    graph: StaticGraph, features: FeatureSettings, active: np.ndarray, centre: np.ndarray, teeth_radius_m: float
) -> Subgraph:
    """The subgraph a step updates (the cutting front and its halo, or the whole graph): one rule for training and stepping."""
    if features.whole_graph:
        return graph.whole()
    return graph.subgraph(graph.region(active, centre, reach_m(teeth_radius_m, features), features.front_hops), features.halo_hops)


#: widths of (node, edge, global) inputs per feature set, before the corner and damage columns
EDGE_GLOBAL_WIDTHS = {"full": (6, 5), "thesis": (2, 3), "socket": (6, 2)}
WIDTHS = {name: (len(NODE_COLUMNS[name]), *widths) for name, widths in EDGE_GLOBAL_WIDTHS.items()}
CORNER_COLUMNS = len(CORNER_NAMES)


#: the cutting prior's floor on sin φ: at the pole the teeth stand still and crush what they cannot cut
PRIOR_MIN_SIN = 0.2
#: the cutting prior's units (u_c, the teeth's edge speed ω·R, ω), set so that over a whole socket's
#: region its per-feed weights average about the contact area alone (a model started from one
#: without the prior starts near its law)
_PRIOR_ENERGY_UNIT_J_M3, _PRIOR_EDGE_SPEED_M_S, _PRIOR_OMEGA_RAD_S = 2.5e8, 3.0, 100.0


def law_weights(graph: StaticGraph, sub: Subgraph, reamer: ReamerState, cutting_energy_j_m3: np.ndarray | None, prior: str) -> np.ndarray:
    """(nodes, 4) weights of each node's reaction-law shares on ``sub`` (the law's columns, reaction and
    torque at no feed and per unit of feed): its share of a contact area (:attr:`StaticGraph.contact_weight`).

    With the cutting prior (``ArchSettings.reaction_prior``) the per-feed columns also carry what the
    solver's cutting law makes an element cost: a tooth cuts the volume its friction work pays
    (μ·N·ω·R sin φ per unit time over u_c), so bone at polar angle φ from the axis, which an advance v
    moves into the teeth at v·cos φ, presses on them with u_c·v·cos φ / (μ·ω·R sin φ) per unit area:
    an axial reaction per unit feed ∝ u_c cos²φ / (ω·R sin φ), a torque per unit feed ∝ u_c cos φ / ω,
    and none behind the equator. The network's share is then a dimensionless correction to it."""
    area = graph.contact_weight[sub.nodes].astype(np.float64)
    weights = np.repeat(area[:, None], 4, axis=1)
    if prior == "cutting":
        if cutting_energy_j_m3 is None:
            raise ValueError("the cutting prior reads every element's cutting energy")
        offset = graph.centroids[sub.nodes] - reamer.centre
        distance = np.maximum(np.linalg.norm(offset, axis=1), 1e-12)
        cos = np.clip(offset @ reamer.axis / distance, 0.0, 1.0)
        sin = np.maximum(np.sqrt(1.0 - cos * cos), PRIOR_MIN_SIN)
        energy = np.asarray(cutting_energy_j_m3, dtype=np.float64)[sub.nodes] / _PRIOR_ENERGY_UNIT_J_M3
        edge_speed = reamer.omega_rad_s * reamer.teeth_radius_m / _PRIOR_EDGE_SPEED_M_S
        weights[:, 1] *= energy * cos * cos / (sin * max(edge_speed, 1e-12))
        weights[:, 3] *= energy * cos / max(reamer.omega_rad_s / _PRIOR_OMEGA_RAD_S, 1e-12)
    elif prior != "none":
        raise ValueError(f"unknown reaction prior {prior!r}")
    return weights.astype(np.float32)


def law_contact_mm2(graph: StaticGraph, sub: Subgraph) -> float:
    """The contact a reaction law sums its shares over (mm²): the contact weights of ``sub``'s region
    (the front and the layer its hop reaches) in area units, Σ V^(2/3). A law learned on small windows
    is an extrapolation on a far larger contact (a seated whole socket: 20–100 times the pushed windows')."""
    return float(graph.contact_weight[sub.region].sum(dtype=np.float64)) * REFERENCE_TET_VOLUME_M3 ** (2.0 / 3.0) * 1e6


def input_widths(features: FeatureSettings) -> tuple[int, int, int]:
    """Widths of (node, edge, global) inputs: the feature set's, plus the corner and damage node columns."""
    _, edge, global_ = WIDTHS[features.feature_set]
    return len(node_columns(features)), edge, global_


@dataclass(frozen=True)
class ReamerState:
    """Where the reamer is at the frame to predict: centre (m), unit axis D, push force (N), spin."""

    centre: np.ndarray
    axis: np.ndarray
    force_n: float
    advance_m: float
    omega_rad_s: float
    teeth_radius_m: float


@dataclass
class GraphBatch:
    """Inputs of one or more subgraphs, concatenated; ``alpha``, ``update`` and (models with damage) ``damage`` per node."""

    nodes: torch.Tensor
    edges: torch.Tensor
    globals_: torch.Tensor
    senders: torch.Tensor
    receivers: torch.Tensor
    node_graph: torch.Tensor
    edge_graph: torch.Tensor
    alpha: torch.Tensor
    update: torch.Tensor
    damage: torch.Tensor | None = None
    #: per subgraph, the next frame's axial reaction (N), motor torque (N·m) and feed (m/s), the case's
    #: push (N) and hold damping (N·s/m); NaN where unknown
    reaction: torch.Tensor | None = None
    #: per node, the (4,) weights its reaction-law shares scale by (:func:`law_weights`)
    contact_weight: torch.Tensor | None = None


def frame_arrays(
    graph: StaticGraph,
    sub: Subgraph,
    alpha_sub: np.ndarray,
    reamer: ReamerState,
    feature_set: FeatureSet,
    threshold: float,
    active_all: np.ndarray,
    damage_sub: np.ndarray | None = None,
    corners: bool = False,
    cutting_energy_j_m3: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(node, edge, global) float32 feature arrays of one subgraph; ``alpha_sub`` is α on ``sub.nodes``,
    ``damage_sub``, when given, D there (the last node column); ``corners`` adds the corner
    distances (``FeatureSettings.corners``) before it.

    ``active_all`` (every element's active flag) gives each node its count of open faces
    (no active tet behind them), which tells the network where the free surface is even when
    the removed neighbours are not in the subgraph. ``cutting_energy_j_m3`` (every element's u_c)
    is read by the socket set only.
    """
    alpha_sub = np.asarray(alpha_sub, dtype=np.float64)
    active = alpha_sub >= threshold
    force = reamer.force_n * reamer.axis
    if feature_set == "thesis":
        broken = ~(active[sub.senders] & active[sub.receivers])
        nodes = np.column_stack([graph.centroids[sub.nodes] - reamer.centre, alpha_sub])
        if damage_sub is not None:
            nodes = np.column_stack([nodes, damage_sub])
        edges = np.stack([~broken, broken], axis=1)
        return nodes.astype(np.float32), edges.astype(np.float32), force[None, :].astype(np.float32)
    if feature_set == "socket":
        return _socket_arrays(graph, sub, alpha_sub, reamer, threshold, active_all, damage_sub, corners, cutting_energy_j_m3)
    # every interactive step and every training sample passes here: one compiled loop per table
    # instead of some twenty NumPy passes over the region (about 2 ms → 0.3 ms a frame)
    nodes = np.empty((len(sub.nodes), WIDTHS["full"][0] + CORNER_COLUMNS * int(corners) + int(damage_sub is not None)), dtype=np.float32)
    _full_node_features(
        sub.nodes,
        graph.centroids,
        graph.radius,
        graph.corners,
        graph.neighbours,
        alpha_sub,
        np.ascontiguousarray(active_all, dtype=np.bool_),
        np.ascontiguousarray(reamer.centre, dtype=np.float64),
        np.ascontiguousarray(reamer.axis, dtype=np.float64),
        reamer.teeth_radius_m,
        reamer.omega_rad_s,
        reamer.advance_m,
        threshold,
        corners,
        _NO_DAMAGE if damage_sub is None else np.asarray(damage_sub, dtype=np.float64),
        nodes,
    )
    edges = np.empty((len(sub.senders), WIDTHS["full"][1]), dtype=np.float32)
    _full_edge_features(sub.nodes, sub.senders, sub.receivers, graph.centroids, active, edges)
    return nodes, edges, np.concatenate([force, [reamer.force_n, reamer.advance_m]])[None, :].astype(np.float32)


_NO_DAMAGE = np.empty(0, dtype=np.float64)


def _socket_arrays(graph, sub, alpha_sub, reamer, threshold, active_all, damage_sub, corners, cutting_energy_j_m3):
    """The socket set's tables (see ``FeatureSettings``): nothing in them depends on the bone frame."""
    if cutting_energy_j_m3 is None:
        raise ValueError("the socket feature set reads every element's cutting energy")
    width = WIDTHS["socket"][0] + CORNER_COLUMNS * int(corners) + int(damage_sub is not None)
    nodes = np.empty((len(sub.nodes), width), dtype=np.float32)
    centre = np.ascontiguousarray(reamer.centre, dtype=np.float64)
    axis = np.ascontiguousarray(reamer.axis, dtype=np.float64)
    _socket_node_features(
        sub.nodes,
        graph.centroids,
        graph.corners,
        graph.neighbours,
        np.ascontiguousarray(cutting_energy_j_m3, dtype=np.float64),
        alpha_sub,
        np.ascontiguousarray(active_all, dtype=np.bool_),
        centre,
        axis,
        reamer.teeth_radius_m,
        reamer.omega_rad_s,
        reamer.advance_m,
        threshold,
        corners,
        _NO_DAMAGE if damage_sub is None else np.asarray(damage_sub, dtype=np.float64),
        nodes,
    )
    edges = np.empty((len(sub.senders), WIDTHS["socket"][1]), dtype=np.float32)
    _socket_edge_features(sub.nodes, sub.senders, sub.receivers, graph.centroids, alpha_sub >= threshold, centre, axis, edges)
    return nodes, edges, np.array([[reamer.advance_m, reamer.teeth_radius_m]], dtype=np.float32)


@njit(cache=True)
def _socket_node_features(
    ids, centroids, corners, neighbours, cutting_energy, alpha_sub, active_all, centre, axis, teeth_radius, omega, advance, threshold,
    with_corners, damage_sub, out,
):  # fmt: skip
    """The socket node table: as the full set's without the bone-frame columns (the relative
    centroid's x, y, z and the distance from the socket's centre), plus log10 u_c (J/mm³)."""
    ax, ay, az = axis[0], axis[1], axis[2]
    px, py, pz = centre[0] - advance * ax, centre[1] - advance * ay, centre[2] - advance * az
    distance = np.empty(4)
    for i in range(len(ids)):
        element = ids[i]
        cx, cy, cz = centroids[element, 0], centroids[element, 1], centroids[element, 2]
        rx, ry, rz = cx - centre[0], cy - centre[1], cz - centre[2]
        axial = rx * ax + ry * ay + rz * az
        tx, ty, tz = rx - axial * ax, ry - axial * ay, rz - axial * az
        radial = np.sqrt(tx * tx + ty * ty + tz * tz)
        open_faces = 0
        for k in range(4):
            neighbour = neighbours[element, k]
            if neighbour < 0 or not active_all[neighbour]:
                open_faces += 1
        out[i, 0] = axial
        out[i, 1] = radial
        out[i, 2] = np.sqrt(rx * rx + ry * ry + rz * rz) - teeth_radius
        out[i, 3] = omega * radial
        out[i, 4] = (cx * ax + cy * ay + cz * az) / max(np.sqrt(cx * cx + cy * cy + cz * cz), 1e-12)
        out[i, 5] = alpha_sub[i]
        out[i, 6] = 1.0 if alpha_sub[i] >= threshold else 0.0
        out[i, 7] = open_faces
        out[i, 8] = np.log10(cutting_energy[element] * 1e-9)
        _corner_and_damage_columns(corners, element, centre, px, py, pz, teeth_radius, distance, with_corners, damage_sub, i, 9, out)


@njit(cache=True)
def _socket_edge_features(ids, senders, receivers, centroids, active_sub, centre, axis, out):
    """The socket edge table: present / broken one-hot, the centroid offset (receiver − sender) along
    the axis, along the receiver's radial direction from it and around it, and its length."""
    for e in range(len(senders)):
        sender, receiver = ids[senders[e]], ids[receivers[e]]
        broken = not (active_sub[senders[e]] and active_sub[receivers[e]])
        out[e, 0] = 0.0 if broken else 1.0
        out[e, 1] = 1.0 if broken else 0.0
        dx = centroids[receiver, 0] - centroids[sender, 0]
        dy = centroids[receiver, 1] - centroids[sender, 1]
        dz = centroids[receiver, 2] - centroids[sender, 2]
        rx, ry, rz = centroids[receiver, 0] - centre[0], centroids[receiver, 1] - centre[1], centroids[receiver, 2] - centre[2]
        along = rx * axis[0] + ry * axis[1] + rz * axis[2]
        ux, uy, uz = rx - along * axis[0], ry - along * axis[1], rz - along * axis[2]
        norm = np.sqrt(ux * ux + uy * uy + uz * uz)
        if norm > 1e-12:
            ux, uy, uz = ux / norm, uy / norm, uz / norm
        axial = dx * axis[0] + dy * axis[1] + dz * axis[2]
        radial = dx * ux + dy * uy + dz * uz
        # around the axis: the offset along D × u
        wx, wy, wz = axis[1] * uz - axis[2] * uy, axis[2] * ux - axis[0] * uz, axis[0] * uy - axis[1] * ux
        out[e, 2] = axial
        out[e, 3] = radial
        out[e, 4] = dx * wx + dy * wy + dz * wz
        out[e, 5] = np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def _full_node_features(
    ids,
    centroids,
    radius,
    corners,
    neighbours,
    alpha_sub,
    active_all,
    centre,
    axis,
    teeth_radius,
    omega,
    advance,
    threshold,
    with_corners,
    damage_sub,
    out,
):
    """The "full" node table (see :func:`frame_arrays`): relative centroid, its axial and radial
    parts, signed distance to the teeth's sphere, cutting speed, cosine to the shell normal,
    distance from the acetabular centre, α, active flag, open faces; then, with corners, the four
    sorted corner distances to the teeth's sphere and the nearest one at the previous centre;
    then D where given. Scalars only in the loop: a temporary array per element costs more than
    the arithmetic."""
    ax, ay, az = axis[0], axis[1], axis[2]
    px, py, pz = centre[0] - advance * ax, centre[1] - advance * ay, centre[2] - advance * az
    distance = np.empty(4)
    for i in range(len(ids)):
        element = ids[i]
        cx, cy, cz = centroids[element, 0], centroids[element, 1], centroids[element, 2]
        rx, ry, rz = cx - centre[0], cy - centre[1], cz - centre[2]
        axial = rx * ax + ry * ay + rz * az
        tx, ty, tz = rx - axial * ax, ry - axial * ay, rz - axial * az
        radial = np.sqrt(tx * tx + ty * ty + tz * tz)
        open_faces = 0
        for k in range(4):
            neighbour = neighbours[element, k]
            if neighbour < 0 or not active_all[neighbour]:
                open_faces += 1
        out[i, 0] = rx
        out[i, 1] = ry
        out[i, 2] = rz
        out[i, 3] = axial
        out[i, 4] = radial
        out[i, 5] = np.sqrt(rx * rx + ry * ry + rz * rz) - teeth_radius
        out[i, 6] = omega * radial
        out[i, 7] = (cx * ax + cy * ay + cz * az) / radius[element]
        out[i, 8] = radius[element]
        out[i, 9] = alpha_sub[i]
        out[i, 10] = 1.0 if alpha_sub[i] >= threshold else 0.0
        out[i, 11] = open_faces
        _corner_and_damage_columns(corners, element, centre, px, py, pz, teeth_radius, distance, with_corners, damage_sub, i, 12, out)


@njit(cache=True)
def _full_edge_features(ids, senders, receivers, centroids, active_sub, out):
    """The "full" edge table: present / broken one-hot, centroid offset (receiver − sender), length."""
    for e in range(len(senders)):
        sender, receiver = senders[e], receivers[e]
        broken = not (active_sub[sender] and active_sub[receiver])
        out[e, 0] = 0.0 if broken else 1.0
        out[e, 1] = 1.0 if broken else 0.0
        length_sq = 0.0
        for j in range(3):
            d = centroids[ids[receiver], j] - centroids[ids[sender], j]
            out[e, 2 + j] = d
            length_sq += d * d
        out[e, 5] = np.sqrt(length_sq)


def batch(
    parts: list[tuple[Subgraph, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]],
    damage: list[np.ndarray] | None = None,
    reaction: list[tuple[float, ...]] | None = None,
    contact_weight: list[np.ndarray] | None = None,
) -> GraphBatch:
    """Concatenate subgraphs: ``parts`` holds (subgraph, α on its nodes, frame_arrays output);
    ``damage``, for models with damage, D on each part's nodes; ``reaction``, for training a
    reaction head, each part's next-frame (reaction N, torque N·m, feed m/s, push N, hold damping
    N·s/m) (see :func:`thrsim.learn.training.next_reaction`); ``contact_weight``,
    for a reaction head, each part's :func:`law_weights`."""
    nodes, edges, globals_, senders, receivers, node_graph, edge_graph, alpha, update = ([] for _ in range(9))
    offset = 0
    for index, (sub, alpha_sub, (n, e, g)) in enumerate(parts):
        nodes.append(n)
        edges.append(e)
        globals_.append(g)
        senders.append(sub.senders + offset)
        receivers.append(sub.receivers + offset)
        node_graph.append(np.full(len(sub.nodes), index))
        edge_graph.append(np.full(len(sub.senders), index))
        alpha.append(np.asarray(alpha_sub, dtype=np.float32))
        mask = np.zeros(len(sub.nodes), dtype=bool)
        mask[: sub.n_region] = True
        update.append(mask)
        offset += len(sub.nodes)

    def cat(items, dtype):
        return torch.from_numpy(np.ascontiguousarray(np.concatenate(items)).astype(dtype, copy=False))

    return GraphBatch(
        nodes=cat(nodes, np.float32),
        edges=cat(edges, np.float32),
        globals_=cat(globals_, np.float32),
        senders=cat(senders, np.int64),
        receivers=cat(receivers, np.int64),
        node_graph=cat(node_graph, np.int64),
        edge_graph=cat(edge_graph, np.int64),
        alpha=cat(alpha, np.float32),
        update=cat(update, np.bool_),
        damage=None if damage is None else cat(damage, np.float32),
        reaction=None if reaction is None else torch.tensor(reaction, dtype=torch.float32).reshape(len(reaction), -1),
        contact_weight=None if contact_weight is None else cat(contact_weight, np.float32),
    )


@njit(cache=True)
def _corner_and_damage_columns(corners, element, centre, px, py, pz, teeth_radius, distance, with_corners, damage_sub, i, column, out):
    """Row ``i`` from ``column`` on: with corners, the four sorted corner distances to the teeth's
    sphere and the nearest one at the previous centre (px, py, pz); then D where given."""
    if with_corners:
        nearest_before = np.inf
        for k in range(4):
            dx, dy, dz = corners[element, k, 0] - centre[0], corners[element, k, 1] - centre[1], corners[element, k, 2] - centre[2]
            value = np.sqrt(dx * dx + dy * dy + dz * dz)
            slot = k  # insertion sort of four
            while slot > 0 and distance[slot - 1] > value:
                distance[slot] = distance[slot - 1]
                slot -= 1
            distance[slot] = value
            dx, dy, dz = corners[element, k, 0] - px, corners[element, k, 1] - py, corners[element, k, 2] - pz
            nearest_before = min(nearest_before, np.sqrt(dx * dx + dy * dy + dz * dz))
        for k in range(4):
            out[i, column + k] = distance[k] - teeth_radius
        out[i, column + 4] = nearest_before - teeth_radius
        column += 5
    if len(damage_sub) > 0:
        out[i, column] = damage_sub[i]
