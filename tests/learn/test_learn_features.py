"""Per-frame node inputs: widths per feature settings, the corner distances and the damage column."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from thrsim.data.synthetic import block_mesh
from thrsim.learn.features import CORNER_COLUMNS, PRIOR_MIN_SIN, WIDTHS, ReamerState, frame_arrays, input_widths, law_weights, node_columns
from thrsim.learn.graph import StaticGraph, Subgraph
from thrsim.learn.settings import FeatureSettings

MESH = block_mesh(n=4)
GRAPH = StaticGraph(MESH)
TEETH_M = 22.5e-3


def _arrays(centre, axis=(0.0, 0.0, -1.0), advance_m=2e-4, damage=None, corners=False, feature_set="full"):
    active = np.ones(MESH.n_tets, dtype=bool)
    sub = GRAPH.subgraph(np.arange(MESH.n_tets), 0)
    alpha = np.full(len(sub.nodes), 0.58, dtype=np.float32)
    reamer = ReamerState(np.asarray(centre, dtype=np.float64), np.asarray(axis, dtype=np.float64), 230.0, advance_m, 136.0, TEETH_M)
    energy = np.where(np.arange(MESH.n_tets) % 2 == 0, 5e8, 1e8)  # cortical and cancellous elements
    return sub, frame_arrays(GRAPH, sub, alpha, reamer, feature_set, 0.3, active, damage, corners, energy)


@pytest.mark.parametrize("feature_set", ["full", "thesis", "socket"])
@pytest.mark.parametrize("damage", [False, True])
@pytest.mark.parametrize("corners", [False, True])
def test_input_widths_are_the_widths_frame_arrays_builds(feature_set, damage, corners):
    if corners and feature_set == "thesis":
        with pytest.raises(ValidationError, match="corners"):
            FeatureSettings(feature_set=feature_set, damage=damage, corners=corners)
        return
    features = FeatureSettings(feature_set=feature_set, damage=damage, corners=corners)
    d = np.linspace(0.0, 1.0, MESH.n_tets, dtype=np.float32) if damage else None
    _, (nodes, edges, globals_) = _arrays((0.0, 0.0, -0.02), damage=d, corners=corners, feature_set=feature_set)
    assert (nodes.shape[1], edges.shape[1], globals_.shape[1]) == input_widths(features)
    assert nodes.shape[1] == len(node_columns(features))  # every column named
    if damage:
        assert np.array_equal(nodes[:, -1], d)  # D is the last column


@settings(max_examples=30, deadline=None)
@given(st.floats(-0.03, -0.01), st.floats(-3e-3, 3e-3), st.floats(0.0, 5e-4))
def test_corner_distances_are_each_tets_corners_to_the_teeth_sphere(z, x, advance_m):
    centre, axis = np.array([x, 0.0, z]), np.array([0.0, 0.0, -1.0])
    sub, (nodes, _, _) = _arrays(centre, advance_m=advance_m, corners=True)
    base = WIDTHS["full"][0]
    now, before = nodes[:, base : base + 4], nodes[:, base + 4]
    assert nodes.shape[1] == base + CORNER_COLUMNS
    corners = MESH.nodes[MESH.tets[sub.nodes]]
    expected = np.sort(np.linalg.norm(corners - centre, axis=2), axis=1) - TEETH_M
    assert np.allclose(now, expected, atol=1e-9)
    assert np.all(np.diff(now, axis=1) >= 0)
    previous = centre - advance_m * axis
    assert np.allclose(before, np.linalg.norm(corners - previous, axis=2).min(axis=1) - TEETH_M, atol=1e-9)
    # distance to a point is convex: the centroid is never farther than its corners' mean
    signed_centroid = nodes[:, 5]
    assert np.all(signed_centroid <= now.mean(axis=1) + 1e-6)


@settings(max_examples=25)
@given(st.integers(0, 2**31 - 1))
def test_full_tables_are_the_formulas_of_each_column(seed):
    """The compiled feature loops against the plain NumPy formulas, column by column, on a random
    partly reamed state, a random subgraph and a random reamer pose."""
    rng = np.random.default_rng(seed)
    alpha_all = np.where(rng.random(MESH.n_tets) < 0.3, 0.0, rng.uniform(0.3, 1.0, MESH.n_tets))
    active_all = alpha_all >= 0.3
    sub = GRAPH.subgraph(np.sort(rng.choice(MESH.n_tets, MESH.n_tets // 2, replace=False)), 1)
    alpha, damage = alpha_all[sub.nodes], rng.random(len(sub.nodes))
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    reamer = ReamerState(rng.uniform(-0.03, 0.03, 3), axis, 230.0, rng.uniform(0, 5e-4), 136.0, TEETH_M)
    nodes, edges, globals_ = frame_arrays(GRAPH, sub, alpha, reamer, "full", 0.3, active_all, damage, corners=True)

    centroids = MESH.centroids[sub.nodes]
    rel = centroids - reamer.centre
    axial = rel @ axis
    radial = np.linalg.norm(rel - axial[:, None] * axis, axis=1)
    radius = np.linalg.norm(centroids, axis=1)
    neighbours = GRAPH.neighbours[sub.nodes]
    open_faces = ((neighbours < 0) | ~active_all[np.maximum(neighbours, 0)]).sum(axis=1)
    corners = MESH.nodes[MESH.tets[sub.nodes]]
    now = np.sort(np.linalg.norm(corners - reamer.centre, axis=2), axis=1) - TEETH_M
    before = np.linalg.norm(corners - (reamer.centre - reamer.advance_m * axis), axis=2).min(axis=1) - TEETH_M
    expected = np.column_stack(
        [
            rel,
            axial,
            radial,
            np.linalg.norm(rel, axis=1) - TEETH_M,
            136.0 * radial,
            centroids @ axis / radius,
            radius,
            alpha,
            alpha >= 0.3,
            open_faces,
            now,
            before,
            damage,
        ]
    )
    assert nodes.dtype == np.float32 and nodes.shape == expected.shape
    assert np.allclose(nodes, expected.astype(np.float32), rtol=1e-6, atol=1e-9)
    present = (alpha >= 0.3)[sub.senders] & (alpha >= 0.3)[sub.receivers]
    offset = centroids[sub.receivers] - centroids[sub.senders]
    expected_edges = np.column_stack([present, ~present, offset, np.linalg.norm(offset, axis=1)])
    assert np.allclose(edges, expected_edges.astype(np.float32), rtol=1e-6, atol=1e-12)
    assert np.allclose(globals_, np.r_[230.0 * axis, 230.0, reamer.advance_m][None, :].astype(np.float32))


def test_the_socket_set_reads_nothing_of_the_bone_frame():
    """Turn the bone, the reamer and its axis together about the origin: the socket inputs stay."""
    from scipy.spatial.transform import Rotation

    turn = Rotation.from_euler("xyz", [25.0, -40.0, 70.0], degrees=True).as_matrix()
    turned = StaticGraph(type(MESH)(nodes=MESH.nodes @ turn.T, tets=MESH.tets, node_sets=MESH.node_sets, fixed_nodes=MESH.fixed_nodes))
    sub = GRAPH.subgraph(np.arange(MESH.n_tets), 0)
    alpha = np.full(len(sub.nodes), 0.58, dtype=np.float32)
    energy = np.where(np.arange(MESH.n_tets) % 2 == 0, 5e8, 1e8)
    centre, axis = np.array([0.001, -0.002, -0.0005]), np.array([0.1, 0.2, -1.0]) / np.linalg.norm([0.1, 0.2, -1.0])
    tables = []
    for graph, rotate in ((GRAPH, np.eye(3)), (turned, turn)):
        reamer = ReamerState(rotate @ centre, rotate @ axis, 230.0, 2e-4, 136.0, TEETH_M)
        tables.append(frame_arrays(graph, sub, alpha, reamer, "socket", 0.3, np.ones(MESH.n_tets, dtype=bool), None, True, energy))
    for before, after in zip(*tables, strict=True):
        assert np.allclose(before, after, atol=1e-6)


def test_the_cutting_prior_weights_the_per_feed_shares_by_what_cutting_each_element_costs():
    graph = StaticGraph(block_mesh(n=4))
    every = Subgraph(np.arange(graph.mesh.n_tets), graph.mesh.n_tets, np.zeros(0, np.int64), np.zeros(0, np.int64))
    axis = np.array([0.0, 0.0, -1.0])
    centre = graph.centroids.mean(axis=0)
    reamer = ReamerState(centre, axis, 230.0, 0.0, 136.0, 24e-3)
    energy = np.where(np.arange(graph.mesh.n_tets) % 2 == 0, 5e8, 1e8)  # cortical and cancellous in turn
    plain = law_weights(graph, every, reamer, energy, "none")
    area = graph.contact_weight
    assert plain.shape == (graph.mesh.n_tets, 4) and np.allclose(plain, area[:, None])
    prior = law_weights(graph, every, reamer, energy, "cutting")
    assert np.allclose(prior[:, [0, 2]], area[:, None])  # the parts at no feed: the contact area alone
    offset = graph.centroids - centre
    cos = offset @ axis / np.linalg.norm(offset, axis=1)
    behind = cos <= 0.0
    assert behind.any() and not prior[behind][:, [1, 3]].any()  # behind the teeth's equator nothing resists an advance
    ahead = np.flatnonzero(cos > 0.5)
    sin = np.maximum(np.sqrt(1.0 - cos[ahead] ** 2), PRIOR_MIN_SIN)
    per_feed = prior[ahead, 1] / area[ahead]
    expected = energy[ahead] * cos[ahead] ** 2 / sin
    assert np.allclose(per_feed / expected, per_feed[0] / expected[0], rtol=1e-4)  # u_c cos²φ / sin φ, one unit for all
    torque = prior[ahead, 3] / area[ahead]
    assert np.allclose(torque / (energy[ahead] * cos[ahead]), torque[0] / (energy[ahead[0]] * cos[ahead[0]]), rtol=1e-4)
    slower = law_weights(graph, every, ReamerState(centre, axis, 230.0, 0.0, 68.0, 24e-3), energy, "cutting")
    assert np.allclose(slower[:, [1, 3]], 2.0 * prior[:, [1, 3]], rtol=1e-5)  # half the spin cuts half as much a turn
    with pytest.raises(ValueError, match="cutting energy"):
        law_weights(graph, every, reamer, None, "cutting")
    with pytest.raises(ValueError, match="unknown reaction prior"):
        law_weights(graph, every, reamer, energy, "friction")
