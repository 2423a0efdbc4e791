"""The static graph: face-sharing edges in both directions, induced subgraphs, the cutting-front region."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thrsim.data.synthetic import block_mesh
from thrsim.learn.graph import StaticGraph, attached_nodes, mesh_digest
from thrsim.learn.metrics import fit_sphere, plate_left_mm3, surface_distance_mm

MESH = block_mesh(n=4)
GRAPH = StaticGraph(MESH)


def _edge_set(senders, receivers, nodes=None):
    if nodes is not None:
        senders, receivers = nodes[senders], nodes[receivers]
    return set(zip(senders.tolist(), receivers.tolist(), strict=True))


def test_edges_join_tets_sharing_a_face_in_both_directions():
    edges = _edge_set(GRAPH.senders, GRAPH.receivers)
    assert len(edges) == GRAPH.n_edges == 2 * len(MESH.adjacency.pairs)
    assert edges == {(r, s) for s, r in edges}
    tets = MESH.tets
    for s, r in list(edges)[:200]:
        assert len(set(tets[s]) & set(tets[r])) == 3
    # every pair of tets sharing three nodes is an edge: brute force on the small block
    shared = {(i, j) for i in range(len(tets)) for j in range(len(tets)) if i != j and len(set(tets[i]) & set(tets[j])) == 3}
    assert shared == edges


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, MESH.n_tets - 1), min_size=1, max_size=60, unique=True), st.integers(0, 2))
def test_subgraph_is_the_induced_subgraph_with_the_region_first(ids, hops):
    region = np.sort(np.array(ids))
    sub = GRAPH.subgraph(region, hops)
    assert np.array_equal(sub.region, region)
    assert len(np.unique(sub.nodes)) == len(sub.nodes)
    inside = set(sub.nodes.tolist())
    expected = {(s, r) for s, r in _edge_set(GRAPH.senders, GRAPH.receivers) if s in inside and r in inside}
    assert _edge_set(sub.senders, sub.receivers, sub.nodes) == expected
    # the halo is exactly the nodes within `hops` face-hops of the region
    reached = set(region.tolist())
    for _ in range(hops):
        reached |= {int(n) for i in list(reached) for n in MESH.adjacency.neighbours[i] if n >= 0}
    assert inside == reached


def test_region_is_the_active_front_near_the_reamer():
    active = np.ones(MESH.n_tets, dtype=bool)
    exposed = GRAPH.exposed(active)
    assert exposed.any() and not exposed.all()
    # intact block: only tets with a face on the articular (inner) side are exposed
    inner_z = MESH.nodes[MESH.node_sets["inner"], 2].max()
    assert np.all(MESH.nodes[MESH.tets[exposed]][:, :, 2].max(axis=1) == inner_z)
    centre = np.array([0.0, 0.0, -22e-3 + 3e-3])
    region = GRAPH.region(active, centre, 3.5e-3, hops=0)
    assert len(region) > 0 and exposed[region].all()
    assert np.all(np.linalg.norm(GRAPH.centroids[region] - centre, axis=1) < 3.5e-3)
    grown = GRAPH.region(active, centre, 3.5e-3, hops=1)
    assert set(region) < set(grown)
    far = GRAPH.region(active, centre + np.array([0.0, 0.0, 0.1]), 3.5e-3, hops=1)
    assert len(far) == 0


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, MESH.n_tets - 1), max_size=80, unique=True), st.floats(1e-3, 6e-3))
def test_region_front_is_the_exposed_set_within_reach(removed, reach):
    active = np.ones(MESH.n_tets, dtype=bool)
    active[removed] = False
    centre = np.array([0.0, 0.0, -22e-3 + 2e-3])
    region = GRAPH.region(active, centre, reach, hops=0)
    close = np.linalg.norm(GRAPH.centroids - centre, axis=1) < reach
    assert np.array_equal(region, np.flatnonzero(GRAPH.exposed(active) & close))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, MESH.n_tets - 1), max_size=80, unique=True), st.floats(1e-3, 6e-3), st.integers(1, 3))
def test_region_grows_hops_face_hops_into_the_active_bone(removed, reach, hops):
    active = np.ones(MESH.n_tets, dtype=bool)
    active[removed] = False
    centre = np.array([0.0, 0.0, -22e-3 + 2e-3])
    # breadth-first search from the front, through active elements only
    reached = set(GRAPH.region(active, centre, reach, hops=0).tolist())
    frontier = set(reached)
    for _ in range(hops):
        frontier = {int(n) for e in frontier for n in GRAPH.neighbours[e] if n >= 0 and active[n]} - reached
        reached |= frontier
    assert np.array_equal(GRAPH.region(active, centre, reach, hops=hops), np.array(sorted(reached), dtype=np.int64))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, MESH.n_tets - 1), max_size=MESH.n_tets, unique=True))
def test_attached_nodes_are_the_nodes_of_active_elements(removed):
    active = np.ones(MESH.n_tets, dtype=bool)
    active[removed] = False
    expected = np.zeros(MESH.n_nodes, dtype=bool)
    expected[MESH.tets[active].ravel()] = True
    assert np.array_equal(attached_nodes(MESH.tets, active, MESH.n_nodes), expected)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, MESH.n_tets - 1), max_size=MESH.n_tets, unique=True), st.integers(0, MESH.n_nodes - 1))
def test_chips_are_the_active_elements_no_face_path_joins_to_held_bone(removed, held_node):
    """Against the solver's own reckoning (SciPy's connected components over active face pairs)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    mesh = dataclasses.replace(MESH, fixed_nodes=np.array([held_node], dtype=np.int32))
    graph = StaticGraph(mesh)
    active = np.ones(mesh.n_tets, dtype=bool)
    active[removed] = False
    pairs = mesh.adjacency.pairs
    live = pairs[active[pairs[:, 0]] & active[pairs[:, 1]]]
    _, label = connected_components(coo_matrix((np.ones(len(live)), (live[:, 0], live[:, 1])), shape=(mesh.n_tets,) * 2), directed=False)
    anchored_labels = np.unique(label[active & np.isin(mesh.tets, [held_node]).any(axis=1)])
    expected = active & ~np.isin(label, anchored_labels)
    assert np.array_equal(graph.chips(active), expected)


def test_removing_elements_moves_the_front_inward():
    active = np.ones(MESH.n_tets, dtype=bool)
    first = GRAPH.exposed(active)
    active[first] = False
    second = GRAPH.exposed(active)
    assert not (second & first).any()
    assert second.any()
    behind = GRAPH.neighbours[second]
    assert np.all(((behind < 0) | ~active[np.maximum(behind, 0)]).any(axis=1))  # each has an open face


def test_mesh_digest_tells_meshes_apart():
    assert mesh_digest(MESH) == mesh_digest(block_mesh(n=4))
    assert mesh_digest(MESH) != mesh_digest(block_mesh(n=3))
    assert mesh_digest(MESH) != mesh_digest(MESH.mirrored())


def test_reamed_surface_is_the_cavity_without_the_unreamed_articular_faces():
    active = np.ones(MESH.n_tets, dtype=bool)
    assert len(GRAPH.reamed_surface(active)) == 0
    inner_z = MESH.nodes[MESH.node_sets["inner"], 2].max()
    boundary = len(MESH.adjacency.boundary_owner)
    articular = int(GRAPH._inner_faces.sum())
    # reamed through: the cavity is the block's outer and side faces, never the articular ones
    assert len(GRAPH.reamed_surface(~active)) == boundary - articular
    active[GRAPH.exposed(active)] = False  # the articular layer
    cavity = GRAPH.reamed_surface(active)
    table = MESH.adjacency.neighbours
    wall = sum(int(active[n]) for i in np.flatnonzero(~active) for n in table[i] if n >= 0)
    sides = sum(int(n < 0) for i in np.flatnonzero(~active) for n in table[i]) - articular
    assert len(cavity) == wall + sides
    assert np.all(cavity[:, 2] < inner_z - 1e-9)


def test_surface_distance_is_symmetric_nearest_face_distance_in_mm():
    grid = np.stack(np.meshgrid(np.arange(10), np.arange(10), [0.0]), axis=-1).reshape(-1, 3) * 1e-3
    assert surface_distance_mm(grid, grid) == (0.0, 0.0)
    mean_mm, max_mm = surface_distance_mm(grid, grid + [0.0, 0.0, 0.2e-3])
    assert np.isclose(mean_mm, 0.2) and np.isclose(max_mm, 0.2)
    assert np.isnan(surface_distance_mm(grid[:0], grid)[0])


def test_a_cavity_s_diameter_is_the_sphere_fitted_to_its_surface():
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(600, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    cap = directions[directions[:, 2] < -0.6]  # a reamed cap, not the whole sphere
    noisy = 0.024 * cap + rng.normal(scale=0.02e-3, size=cap.shape) + [0.01, -0.02, 0.03]
    centre, radius = fit_sphere(noisy)
    assert abs(2e3 * radius - 48.0) < 0.1 and np.linalg.norm(centre - [0.01, -0.02, 0.03]) < 0.05e-3
    plane = np.stack(np.meshgrid(np.arange(10), np.arange(10), [0.0]), axis=-1).reshape(-1, 3) * 1e-3
    assert fit_sphere(plane) is None and fit_sphere(noisy[:9]) is None


def test_the_plate_left_is_the_live_cortical_bone_just_ahead_of_the_teeth():
    radius, axis, centre = 0.024, np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.01])
    polar = np.radians([0.0, 30.0, 30.0, 60.0, 180.0, 0.0, 0.0, 10.0])  # from the axis
    beyond = np.array([0.5, 1.0, 1.4, 1.0, 1.0, 1.7, -0.3, 0.7]) * 1e-3  # past the teeth's sphere
    centroids = centre + (radius + beyond)[:, None] * np.column_stack([np.sin(polar), np.zeros(8), np.cos(polar)])
    volumes = np.arange(1.0, 9.0) * 1e-9  # 1 … 8 mm³
    cortical = np.array([True] * 7 + [False])
    alive = np.ones(8, dtype=bool)
    # in the plate: the first three (within 45° of the axis, 0–1.5 mm beyond); not 60°, behind, 1.7 mm,
    # inside the teeth or cancellous
    assert plate_left_mm3(centroids, volumes, cortical, alive, centre, axis, radius) == pytest.approx(1 + 2 + 3)
    alive[1] = False
    assert plate_left_mm3(centroids, volumes, cortical, alive, centre, axis, radius) == pytest.approx(1 + 3)
    assert plate_left_mm3(centroids, volumes, cortical, alive, centre, -axis, radius) == pytest.approx(5)  # the one behind


def test_the_socket_s_articular_face_is_where_the_cutting_front_starts():
    from thrsim.config import SocketConfig
    from thrsim.geometry.socket import generate_socket

    mesh = generate_socket(SocketConfig(element_size_mm=1.5, window_polar_deg=0.0, window_half_angle_deg=15.0))
    graph = StaticGraph(mesh)
    exposed = graph.exposed(np.ones(mesh.n_tets, dtype=bool))
    assert exposed.any()
    on_articular = np.isin(mesh.tets, mesh.node_sets["articular"]).sum(axis=1) >= 3
    assert set(np.flatnonzero(exposed)) <= set(np.flatnonzero(on_articular))
    pole = np.array([0.0, 0.0, -1.0])
    region = graph.region(np.ones(mesh.n_tets, dtype=bool), np.zeros(3), 0.5 * SocketConfig().socket_diameter_mm * 1e-3 + 1e-3, 1)
    assert len(region) > 0 and (graph.centroids[region] @ pole > 0).all()


def test_threads_sharing_a_graph_get_the_subgraphs_and_regions_each_would_alone():
    """A server's sessions share their model's graph; one starts on a worker thread while another steps."""
    import sys
    import threading

    rng = np.random.default_rng(3)
    active = rng.random(MESH.n_tets) > 0.2
    centres = MESH.centroids[rng.choice(MESH.n_tets, 40)]
    reach = 0.3 * float(np.ptp(MESH.nodes[:, 0]))
    queries = [(np.sort(rng.choice(MESH.n_tets, 30, replace=False)), centre) for centre in centres]

    def answers():
        found = []
        for region, centre in queries:
            sub = GRAPH.subgraph(region, 2)
            found.append((sub.nodes, sub.senders, GRAPH.region(active, centre, reach, 1)))
        return found

    alone = answers()
    results: list = []
    start = threading.Barrier(4)

    def worker():
        start.wait()
        results.append([answers() for _ in range(5)])

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads between nearly every bytecode
    try:
        threads = [threading.Thread(target=worker) for _ in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    finally:
        sys.setswitchinterval(interval)
    assert len(results) == 4
    for runs in results:
        for run in runs:
            for (nodes, senders, region), (nodes0, senders0, region0) in zip(run, alone, strict=True):
                assert np.array_equal(nodes, nodes0) and np.array_equal(senders, senders0) and np.array_equal(region, region0)


def test_cavity_depth_error_is_the_whole_cavity_s_so_a_window_that_cuts_nothing_new_errs_by_what_the_solver_cut():
    from thrsim.learn.evaluation import cavity_errors

    axis = np.array([0.0, 0.0, -1.0])
    depth = -GRAPH.centroids[:, 2]  # along the axis from a start at z = 0
    start = np.zeros(3)
    before = depth < np.quantile(depth, 0.2)  # the cavity when the window starts
    solver = depth < np.quantile(depth, 0.4)
    expected = (depth[solver].max() - depth[before].max()) * 1e3

    def depth_error(predicted, true):
        return cavity_errors(GRAPH, predicted, true, before, start, axis)["cavity_depth_error_mm"]

    assert depth_error(before, solver) == pytest.approx(-expected, abs=1e-9)  # the window cut nothing new: short by what the solver cut
    assert expected > 0 and depth_error(solver, solver) == 0.0
    assert depth_error(solver, np.zeros_like(solver)) is None  # the solver cut nothing


def test_the_fitted_sphere_s_depth_follows_the_reamed_wall_where_elements_crushed_ahead_move_the_deepest():
    from thrsim.config import SocketConfig
    from thrsim.geometry.socket import generate_socket
    from thrsim.learn.evaluation import cavity_errors

    config = SocketConfig(element_size_mm=2.0, coarse_element_size_mm=4.0)
    graph = StaticGraph(generate_socket(config))
    axis, start, nothing = np.array([0.0, 0.0, -1.0]), np.zeros(3), np.zeros(graph.n_nodes, dtype=bool)
    distance = np.linalg.norm(graph.centroids, axis=1)
    radius_m = config.socket_diameter_mm / 2e3
    shallow, deep = (distance < radius_m + extra_m for extra_m in (1e-3, 2e-3))
    errors = cavity_errors(graph, shallow, deep, nothing, start, axis)
    # a reamer 1 mm larger reams 1 mm deeper: both depths see it, to within an element (centroids decide what is removed)
    for depth in ("cavity_depth_error_mm", "sphere_depth_error_mm"):
        assert errors[depth] == pytest.approx(-1.0, abs=config.element_size_mm / 2)
    ahead = np.flatnonzero(
        ~deep & (graph.neighbours >= 0).all(axis=1) & (distance < radius_m + 4e-3) & (graph.centroids @ axis > 0.5 * distance)
    )
    crushed = deep.copy()
    crushed[np.random.default_rng(0).choice(ahead, 30, replace=False)] = True  # deleted up to 2 mm ahead of the wall, as damage deletes
    errors = cavity_errors(graph, crushed, deep, nothing, start, axis)
    assert errors["cavity_depth_error_mm"] > 1.0 and abs(errors["sphere_depth_error_mm"]) < 0.3
