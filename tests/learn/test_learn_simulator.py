"""``thrsim.ReamingSimulator``: the interactive API, both sides, both modes, and refused input."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from checkout_cli import checkout_env
from learn_helpers import REPO

from thrsim.errors import ThrsimInputError
from thrsim.geometry.reaming_path import tip_exit_depth
from thrsim.learn.features import reach_m
from thrsim.learn.rollout import BoneState
from thrsim.learn.simulator import PASSED_THROUGH, PERFORATED, ReamingSimulator, angles_of, start_position

AXIS = np.array([np.sin(np.radians(15)) * np.cos(np.radians(30)), np.sin(np.radians(15)) * np.sin(np.radians(30)), -np.cos(np.radians(15))])


@pytest.fixture(scope="module")
def simulator(tiny_model):
    return ReamingSimulator(tiny_model)


def test_steps_return_the_bone_state_and_advance_along_the_axis(simulator):
    simulator.reset("right")
    n = simulator.n_elements
    start = simulator.reamer_start(AXIS)
    previous_removed = np.zeros(n, dtype=bool)
    for frame in range(1, 6):
        state = simulator.step(AXIS, 230.0)
        assert state.frame == frame
        assert state.alpha.shape == (n,) and state.alpha.dtype == np.float32
        assert np.all((state.alpha >= 0) & (state.alpha <= 1))
        assert np.array_equal(state.removed, state.alpha < 0.3)
        assert np.all(state.removed[previous_removed])  # removed elements stay removed
        assert np.array_equal(state.newly_removed, np.flatnonzero(state.removed & ~previous_removed))
        assert np.isclose(state.removed_volume_m3, simulator.model.graph.volumes[state.removed].sum())
        offset = state.reamer_position - start
        assert np.allclose(offset - (offset @ AXIS) * AXIS, 0.0, atol=1e-12)  # on the axis line
        previous_removed = state.removed
    assert simulator.frame == 5


def test_a_given_position_forces_the_reamer(simulator):
    simulator.reset()
    target = simulator.reamer_start(AXIS) + 1e-4 * AXIS
    state = simulator.step(AXIS, 230.0, reamer_position=target)
    assert np.array_equal(state.reamer_position, target)


def test_left_side_is_the_mirror_of_the_right(simulator):
    mirror = np.array([-1.0, 1.0, 1.0])
    simulator.reset("right")
    right = [simulator.step(AXIS, 230.0) for _ in range(3)]
    simulator.reset("left")
    left = [simulator.step(AXIS * mirror, 230.0) for _ in range(3)]
    for r, l in zip(right, left, strict=True):
        assert np.array_equal(r.alpha, l.alpha)
        assert np.allclose(l.reamer_position, r.reamer_position * mirror)
    assert np.allclose(simulator.mesh.nodes, simulator.right_mesh.nodes * mirror)


def test_a_snapshot_restores_a_frame_and_the_run_goes_on_as_before(simulator):
    simulator.reset()
    for _ in range(2):
        simulator.step(AXIS, 230.0)
    taken = simulator.snapshot()
    first = [simulator.step(AXIS, 230.0) for _ in range(3)]
    simulator.restore(taken)
    assert simulator.frame == 2 and np.array_equal(simulator.alpha, taken.bone.alpha)
    assert np.array_equal(simulator.bone.damage, taken.bone.damage) and taken.bone.damage.any()  # damage is part of the state
    again = [simulator.step(AXIS, 230.0) for _ in range(3)]
    for a, b in zip(first, again, strict=True):
        assert a.frame == b.frame and np.array_equal(a.alpha, b.alpha) and np.array_equal(a.reamer_position, b.reamer_position)
    assert first[-1].frame == 5 and simulator.depth_m > 0


def test_reset_restores_the_intact_bone(simulator):
    simulator.reset()
    for _ in range(3):
        simulator.step(AXIS, 230.0)
    simulator.reset()
    assert simulator.frame == 0 and not simulator.removed.any()
    assert np.all(simulator.alpha == simulator.alpha[0])


@pytest.mark.parametrize(
    "axis, force, message",
    [
        ((np.nan, 0.0, -1.0), 230.0, "NaN"),
        ((0.0, 0.0, 0.0), 230.0, "zero length"),
        ((0.0, -1.0), 230.0, "3 components"),
        (AXIS, -1.0, "non-negative"),
        (AXIS, float("inf"), "finite"),
        (AXIS, "much", "number"),
    ],
)
def test_bad_input_is_refused(simulator, axis, force, message):
    simulator.reset()
    with pytest.raises(ThrsimInputError, match=message):
        simulator.step(axis, force)
    assert simulator.frame == 0


def test_unknown_side_and_wrong_model_dir_are_refused(simulator, tmp_path):
    with pytest.raises(ThrsimInputError, match="side: must be right or left"):
        simulator.reset("middle")
    with pytest.raises(ThrsimInputError, match="not a thrsim model"):
        ReamingSimulator(tmp_path)


def test_angles_and_start_position():
    gamma, theta = angles_of(AXIS)
    assert np.isclose(gamma, 15.0) and np.isclose(theta, 30.0)
    assert angles_of(np.array([0.0, 0.0, -1.0])) == (0.0, 0.0)
    nodes = np.array([[0.0, 0.0, -0.022], [0.005, 0.0, -0.0215]])
    centre = start_position(nodes, np.array([0.0, 0.0, -1.0]), 0.0229)
    assert np.isclose(np.linalg.norm(nodes - centre, axis=1).min(), 0.0229 + 5e-5, atol=1e-9)
    with pytest.raises(ThrsimInputError, match="misses the bone"):
        start_position(nodes, np.array([1.0, 0.0, 0.0]), 0.003)


def test_thrsim_exports_the_simulator_lazily():
    code = "import sys, thrsim; assert 'torch' not in sys.modules; from thrsim.learn.simulator import ReamingSimulator as R; assert thrsim.ReamingSimulator is R; print('ok')"
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120, env=checkout_env())
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr


def test_threads_limit_numpys_blas_as_well_as_torch(tiny_model):
    code = (
        "import sys, torch; from threadpoolctl import threadpool_info; from thrsim.learn.simulator import ReamingSimulator; "
        "ReamingSimulator(sys.argv[1], threads=1); "
        "blas = [i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas']; "
        "print(torch.get_num_threads(), blas)"
    )
    env = {**checkout_env(), "OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"}
    result = subprocess.run([sys.executable, "-c", code, str(tiny_model)], cwd=REPO, capture_output=True, text=True, timeout=120, env=env)
    assert result.returncode == 0, result.stderr
    torch_threads, blas = result.stdout.split(" ", 1)
    assert torch_threads == "1" and blas.strip() in ("[1]", "[1, 1]")


def test_only_the_region_near_the_reamer_changes(simulator):
    model = simulator.model
    step = simulator._step
    alpha = np.full(simulator.n_elements, 0.58, dtype=np.float32)
    centre = simulator.reamer_start(AXIS) + 5e-4 * AXIS
    region = model.graph.region(
        alpha >= 0.3, centre, reach_m(step.teeth_radius_m, model.settings.features), model.settings.features.front_hops
    )
    assert 0 < len(region) < simulator.n_elements
    out = step(BoneState.start(alpha), centre, AXIS, 230.0, 5e-4, 136.0)
    outside = np.ones(simulator.n_elements, dtype=bool)
    outside[region] = False
    assert np.array_equal(out.alpha[outside], alpha[outside]) and not out.hazard[outside].any() and not out.damage[outside].any()
    far = step(BoneState.start(alpha), centre - 0.05 * AXIS, AXIS, 230.0, 0.0, 136.0)
    assert np.array_equal(far.alpha, alpha) and not far.hazard.any() and not far.damage.any()


def test_a_rollout_ends_where_the_solver_ends_its_cases(simulator):
    mesh = simulator.model.mesh
    teeth = simulator.model.teeth_radius_m
    pole = np.array([0.0, 0.0, -1.0])
    exit_depth = tip_exit_depth(mesh, pole)
    assert exit_depth is not None  # the patch lies under the pole
    simulator.reset("right")
    short = simulator.step(pole, 230.0, reamer_position=(exit_depth - teeth - 1e-4) * pole)
    assert short.end_reason is None
    assert simulator.step(pole, 230.0, reamer_position=(exit_depth - teeth + 1e-4) * pole).end_reason == PERFORATED
    # a reamer tilted past the patch has no bone under its tip: it ends only when its path is clear
    tilted = np.array([np.sin(np.radians(60)), 0.0, -np.cos(np.radians(60))])
    assert tip_exit_depth(mesh, tilted) is None
    simulator.reset("right")
    start = simulator.reamer_start(tilted)
    assert simulator.step(tilted, 230.0, reamer_position=start).end_reason is None
    beyond = start + 0.06 * tilted  # the head's equatorial plane past every node
    assert simulator.step(tilted, 230.0, reamer_position=beyond).end_reason == PASSED_THROUGH


def test_the_compiled_network_removes_what_the_eager_one_removes(tiny_model):
    eager, compiled = ReamingSimulator(tiny_model), ReamingSimulator(tiny_model, compile=True)
    assert compiled.compiled and compiled.compile_error is None and not eager.compiled
    intact = eager.alpha.copy()
    mismatched = removed = 0
    for _ in range(30):
        a, b = eager.step(AXIS, 230.0), compiled.step(AXIS, 230.0)
        mismatched += int((a.removed ^ b.removed).sum())
        removed += int(a.removed.sum())
        assert np.allclose(a.reamer_position, b.reamer_position, atol=1e-6)
        live = ~(a.removed | b.removed)
        assert np.abs(a.alpha[live] - b.alpha[live]).max() < 1e-3
    assert (eager.alpha != intact).sum() >= 20  # the network did change the bone
    assert np.abs(eager.bone.damage - compiled.bone.damage).max() < 1e-3
    assert mismatched <= 0.01 * max(removed, 1)  # fused kernels round differently, rarely across the threshold


def test_the_compiled_network_never_compiles_again_for_a_tiny_region(tiny_model):
    """A region of one element, or one with no edges (a bone nearly gone), once compiled the network
    again inside a session, for seconds; the values stay the eager network's."""
    import dataclasses

    import torch

    compiled, eager = ReamingSimulator(tiny_model, compile=True), ReamingSimulator(tiny_model)
    example = compiled.example_inputs()

    def first(n_nodes, n_edges):  # the example's first nodes, and up to n_edges of the edges among them
        among = torch.nonzero((example.senders < n_nodes) & (example.receivers < n_nodes)).ravel()[:n_edges]
        return dataclasses.replace(
            example,
            nodes=example.nodes[:n_nodes],
            edges=example.edges[among],
            senders=example.senders[among],
            receivers=example.receivers[among],
            node_graph=example.node_graph[:n_nodes],
            edge_graph=example.edge_graph[among],
            alpha=example.alpha[:n_nodes],
            update=example.update[:n_nodes],
        )

    no_edges = torch.from_numpy(np.empty(0, dtype=np.int64))  # stride 0, as NumPy leaves an empty index
    batches = [first(1, 0), first(2, 0), first(3, 1), first(40, 30)]
    batches.append(dataclasses.replace(first(2, 0), senders=no_edges, receivers=no_edges, edge_graph=no_edges))
    with torch._dynamo.config.patch(error_on_recompile=True), torch.inference_mode():
        for batch in batches:
            got = compiled.model.gn.network(*compiled.model.gn.normalised_inputs(batch))
            want = eager.model.gn.network(*eager.model.gn.normalised_inputs(batch))
            assert got.shape == want.shape and torch.allclose(got, want, atol=1e-4)


def test_a_failed_compile_leaves_the_eager_network_and_says_why(tiny_model, monkeypatch):
    import torch

    class Broken(torch.nn.Module):
        def forward(self, *args):
            raise RuntimeError("no C++ compiler found\nsecond line")

    monkeypatch.setattr(torch, "compile", lambda module, **kwargs: Broken())
    simulator = ReamingSimulator(tiny_model, compile=True)
    assert not simulator.compiled
    assert simulator.compile_error == "RuntimeError: no C++ compiler found"
    assert simulator.step(AXIS, 230.0).frame == 1


@pytest.mark.parametrize("bone", ["the model's own", "the whole socket at 1.5 mm"])
def test_a_fresh_simulator_has_its_kernels_loaded_before_its_first_frame_in_contact(bone):
    """Numba loads a kernel's cached machine code on its first call (and compiles it on a fresh
    install): once in a trainee's first frame in contact (a 40-90 ms tick; 1.6 s uncached), now in
    the simulator's warm-up, on any bone it is given (on the whole socket the warm-up's reamer once
    stopped short of the bone). A fresh interpreter, so that no other test has called them first."""
    mesh = "None" if bone == "the model's own" else "generate_socket(SocketConfig(element_size_mm=1.5))"
    script = (
        "from thrsim.config import SocketConfig\n"
        "from thrsim.geometry.socket import generate_socket\n"
        "from thrsim.learn.simulator import ReamingSimulator\n"
        "from thrsim.learn.model_dir import SHIPPED_SOCKET_MODEL, load_model\n"
        "from thrsim.learn import features, graph\n"
        f"simulator = ReamingSimulator(model=load_model(SHIPPED_SOCKET_MODEL), mesh={mesh})\n"
        "kernels = [graph._cutting_front, graph.attached_nodes, graph.unanchored_elements, features._socket_node_features,\n"
        "           features._socket_edge_features, graph._front_entry]\n"
        "print([len(kernel.signatures) for kernel in kernels], simulator.frame, int(simulator.removed.sum()))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=600, env=checkout_env(), check=True
    )
    assert done.stdout.split() == ["[1,", "1,", "1,", "1,", "1,", "1]", "0", "0"]  # every kernel loaded, the bone intact
