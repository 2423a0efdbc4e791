"""Per-frame inputs of the learned simulator (the thesis's graph [7.3.1], plus what helps; see FeatureSettings).

Everything is computed on a :class:`~thrsim.learn.graph.Subgraph` only (the region near the
reamer and its halo), from arrays already in memory: a centroid table, α, the reamer centre,
axis and force. Several subgraphs are batched by concatenation with index offsets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from thrsim.learn.graph import StaticGraph, Subgraph
from thrsim.learn.settings import FeatureSet, FeatureSettings

#: widths of (node, edge, global) inputs per feature set, before the corner and damage columns
WIDTHS = {"full": (12, 6, 5), "thesis": (4, 2, 3)}
#: node columns of ``FeatureSettings.corners``: four sorted corner distances, the nearest at t − 1
CORNER_COLUMNS = 5


def input_widths(features: FeatureSettings) -> tuple[int, int, int]:
    """Widths of (node, edge, global) inputs: the feature set's, plus the corner and damage node columns."""
    node, edge, global_ = WIDTHS[features.feature_set]
    return node + CORNER_COLUMNS * int(features.corners) + int(features.damage), edge, global_


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

    def network_args(self) -> tuple:
        return (self.nodes, self.edges, self.globals_, self.senders, self.receivers, self.node_graph, self.edge_graph)


def frame_arrays(graph: StaticGraph, sub: Subgraph, alpha_sub: np.ndarray, reamer: ReamerState, feature_set: FeatureSet, threshold: float, active_all: np.ndarray, damage_sub: np.ndarray | None = None, corners: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(node, edge, global) float32 feature arrays of one subgraph; ``alpha_sub`` is α on ``sub.nodes``,
    ``damage_sub``, when given, D there (the last node column); ``corners`` adds the corner
    distances (``FeatureSettings.corners``) before it.

    ``active_all`` (every element's active flag) gives each node its count of open faces
    (no active tet behind them), which tells the network where the free surface is even when
    the removed neighbours are not in the subgraph.
    """
    centroids = graph.centroids[sub.nodes]
    rel = centroids - reamer.centre
    alpha_sub = np.asarray(alpha_sub, dtype=np.float64)
    active = alpha_sub >= threshold
    broken = ~(active[sub.senders] & active[sub.receivers])
    one_hot = np.stack([~broken, broken], axis=1)
    force = reamer.force_n * reamer.axis
    if feature_set == "thesis":
        nodes = np.column_stack([rel, alpha_sub])
        edges = one_hot
        globals_ = force[None, :]
    else:
        axial = rel @ reamer.axis
        radial = np.linalg.norm(rel - axial[:, None] * reamer.axis, axis=1)
        signed = np.linalg.norm(rel, axis=1) - reamer.teeth_radius_m
        radius = graph.radius[sub.nodes]
        normal_cos = (centroids @ reamer.axis) / radius
        open_faces = graph.open_faces(active_all, sub.nodes)
        nodes = np.column_stack([rel, axial, radial, signed, reamer.omega_rad_s * radial, normal_cos, radius, alpha_sub, active, open_faces])
        if corners:
            tet_corners = graph.corners[sub.nodes]
            now = np.sort(np.linalg.norm(tet_corners - reamer.centre, axis=2), axis=1) - reamer.teeth_radius_m
            before = np.linalg.norm(tet_corners - (reamer.centre - reamer.advance_m * reamer.axis), axis=2).min(axis=1) - reamer.teeth_radius_m
            nodes = np.column_stack([nodes, now, before])
        offset = centroids[sub.receivers] - centroids[sub.senders]
        edges = np.column_stack([one_hot, offset, np.linalg.norm(offset, axis=1)])
        globals_ = np.concatenate([force, [reamer.force_n, reamer.advance_m]])[None, :]
    if damage_sub is not None:
        nodes = np.column_stack([nodes, damage_sub])
    return nodes.astype(np.float32), edges.astype(np.float32), globals_.astype(np.float32)


def batch(parts: list[tuple[Subgraph, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]], damage: list[np.ndarray] | None = None) -> GraphBatch:
    """Concatenate subgraphs: ``parts`` holds (subgraph, α on its nodes, frame_arrays output);
    ``damage``, for models with damage, D on each part's nodes."""
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
    )
