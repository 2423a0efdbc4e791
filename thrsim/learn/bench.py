"""Speed of the learned simulator (``thrsim bench --learned``); figures, never unit-test assertions.

``production``: median ms per frame of :meth:`ReamingSimulator.step` plus the reamer feed's own
cost, on the default mesh, the reamer pushed along γ 15°, θ 30° at a steady feed (so the region
depends on the mesh, not on what the weights learned), the network eager as ``thrsim ream`` runs
it; ``production_compiled``: the same compiled, as ``thrsim serve`` runs it, with the seconds
compiling took; ``thesis_way``: the thesis's Algorithm 1 (every element every frame, the graph
rebuilt each frame); ``larger_mesh``: patches of about 4× the elements, ``thicker`` and
``wider``. Without a model the networks keep their initial weights, whose removal hazard empties
the region every frame: time a trained model. Figures: the docs' Benchmarks and validation page.
"""

from __future__ import annotations

import copy
import time
from dataclasses import replace
from typing import Any

import numpy as np
import torch

from thrsim.config import PUSH_FORCE_N, BonePatchConfig, LabelConfig, Orientation
from thrsim.geometry.adjacency import face_adjacency
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.tet_metrics import centroids
from thrsim.learn.advance import FEATURES, ArrayRegressor
from thrsim.learn.features import ReamerState, batch, frame_arrays
from thrsim.learn.graph import StaticGraph, Subgraph
from thrsim.learn.learned_simulator import LearnedSimulator
from thrsim.learn.model_dir import LoadedModel
from thrsim.learn.settings import ModelSettings, preset
from thrsim.learn.simulator import ReamingSimulator, start_position

#: reamer feed per frame driven in the benchmark (m): a steady push into the bone
FEED_M = 2e-5


def untrained_model(mesh: TetMesh, settings: ModelSettings, teeth_radius_m: float = 22.9e-3, omega_rad_s: float = 136.0) -> LoadedModel:
    """A model with initial weights and unit normalisers on ``mesh`` (for timing only)."""
    torch.manual_seed(0)
    labels = LabelConfig()
    gn, mlp = LearnedSimulator(settings, "gn", labels.removed_threshold), LearnedSimulator(settings, "mlp", labels.removed_threshold)
    width = len(FEATURES)
    advance = ArrayRegressor(
        "linear",
        {
            "mean": np.zeros(width),
            "scale": np.ones(width),
            "coef": np.zeros(width),
            "intercept": np.array(FEED_M * 1e3),
            "target_range": np.array([0.0, 1.0]),
            "n_features": np.array(width),
        },
    )
    card = {"labels": labels.model_dump(), "reamer": {"teeth_radius_m": teeth_radius_m, "omega_rad_s": omega_rad_s}, "arch": "untrained"}
    return LoadedModel(
        path=None, card=card, settings=settings, gn=gn.eval(), mlp=mlp.eval(), advance=advance, mesh=mesh, graph=StaticGraph(mesh)
    )


def time_production(
    model: LoadedModel, frames: int, inclination_deg: float = 15.0, anteversion_deg: float = 30.0, compile: bool = False
) -> dict:
    started = time.perf_counter()
    simulator = ReamingSimulator(model=model, threads=1, compile=compile)  # as the server runs it
    compile_s = time.perf_counter() - started
    axis = np.array(Orientation(inclination_deg=inclination_deg, anteversion_deg=anteversion_deg).reamer_axis)
    # a steady feed, not the model's own: the region then depends on the mesh, not on what the weights learned
    centre = start_position(model.mesh.nodes, axis, model.teeth_radius_m)
    simulator.step(axis, PUSH_FORCE_N, centre)  # warm-up
    feed = model.reamer_feed()
    times, regions, feed_times = [], [], []
    for k in range(1, frames + 1):
        started = time.perf_counter()
        feed.advance_m(
            simulator.alpha,
            centre + (k - 1) * FEED_M * axis,
            centre,
            axis,
            inclination_deg,
            anteversion_deg,
            PUSH_FORCE_N,
            PUSH_FORCE_N * k * model.frame_dt_s,
        )
        feed_times.append(time.perf_counter() - started)
        state = simulator.step(axis, PUSH_FORCE_N, centre + k * FEED_M * axis)
        times.append(state.seconds + feed_times[-1])
        regions.append(simulator._step.last.region)
    return {
        "elements": model.mesh.n_tets,
        "frames": frames,
        "ms_per_frame_median": 1e3 * float(np.median(times)),
        "ms_per_frame_p90": 1e3 * float(np.percentile(times, 90)),
        "region_elements_median": int(np.median(regions)),
        "feed_ms_median": 1e3 * float(np.median(feed_times)),
        "feed_mm_per_frame": FEED_M * 1e3,
        "case": f"inclination {inclination_deg:g} deg, anteversion {anteversion_deg:g} deg, steady feed (the reamer feed's own cost included)",
        "network": "compiled" if simulator.compiled else "eager",
        **({"compile_s": compile_s, "compile_error": simulator.compile_error} if compile else {}),
    }


def time_thesis_way(
    mesh: TetMesh, frames: int, teeth_radius_m: float = 22.9e-3, inclination_deg: float = 15.0, anteversion_deg: float = 30.0
) -> dict:
    """Algorithm 1: rebuild the graph input from the mesh every frame, run the thesis's GN on all of it."""
    settings = preset("thesis")
    model = untrained_model(mesh, settings, teeth_radius_m)
    axis = np.array(Orientation(inclination_deg=inclination_deg, anteversion_deg=anteversion_deg).reamer_axis)
    centre = start_position(mesh.nodes, axis, teeth_radius_m)
    alpha = np.full(mesh.n_tets, 0.58, dtype=np.float32)
    build, network = [], []
    for k in range(frames + 1):
        t0 = time.perf_counter()
        adjacency = face_adjacency(mesh.tets)
        pairs = adjacency.pairs
        sub = Subgraph(
            nodes=np.arange(mesh.n_tets),
            n_region=mesh.n_tets,
            senders=np.concatenate([pairs[:, 0], pairs[:, 1]]),
            receivers=np.concatenate([pairs[:, 1], pairs[:, 0]]),
        )
        graph = model.graph
        graph.centroids = centroids(mesh.nodes, mesh.tets)  # Algorithm 1, line 2: recomputed per frame
        reamer = ReamerState(centre + k * FEED_M * axis, axis, PUSH_FORCE_N, FEED_M, 136.0, teeth_radius_m)
        inputs = batch([(sub, alpha, frame_arrays(graph, sub, alpha, reamer, "thesis", 0.3, alpha >= 0.3))])
        t1 = time.perf_counter()
        with torch.inference_mode():
            alpha = model.gn.alpha_next(inputs).numpy()
        t2 = time.perf_counter()
        if k:  # the first frame warms up
            build.append(t1 - t0)
            network.append(t2 - t1)
    total = np.array(build) + np.array(network)
    return {
        "elements": mesh.n_tets,
        "frames": frames,
        "ms_per_frame_median": 1e3 * float(np.median(total)),
        "graph_build_ms_median": 1e3 * float(np.median(build)),
        "network_ms_median": 1e3 * float(np.median(network)),
        "thesis_reported_ms": {"network": 127.0, "graph_and_render": 579.11, "total": 706.0},
    }


def run_learned_benchmarks(
    model: LoadedModel | None = None,
    frames: int = 20,
    thesis_frames: int = 3,
    larger: bool = True,
    solver_seconds_per_frame: float | None = None,
) -> dict:
    from thrsim.geometry.bone_patch import generate_bone_patch

    if model is None:
        model = untrained_model(generate_bone_patch(BonePatchConfig()), preset("production"))
    result: dict[str, Any] = {"threads": torch.get_num_threads(), "production": time_production(model, frames)}
    compiled_model = replace(model, gn=copy.deepcopy(model.gn))  # compiling changes the network in place
    result["production_compiled"] = time_production(compiled_model, frames, compile=True)
    result["thesis_way"] = time_thesis_way(model.mesh, thesis_frames, model.teeth_radius_m)
    for key in ("production", "production_compiled"):
        result[f"speedup_vs_thesis_way{key[len('production') :]}"] = (
            result["thesis_way"]["ms_per_frame_median"] / result[key]["ms_per_frame_median"]
        )
    if solver_seconds_per_frame is not None:
        result["solver_ms_per_frame"] = solver_seconds_per_frame * 1e3
        result["speedup_vs_solver"] = solver_seconds_per_frame * 1e3 / result["production"]["ms_per_frame_median"]
    if larger:
        bone = BonePatchConfig()
        result["larger_mesh"] = {}
        for name, config in (
            ("thicker", BonePatchConfig(thickness_mm=4 * bone.thickness_mm)),
            ("wider", BonePatchConfig(half_angle_deg=_four_times_area(bone.half_angle_deg))),
        ):
            big = replace(
                model, path=None, mesh=(mesh := generate_bone_patch(config)), graph=StaticGraph(mesh)
            )  # the same networks: they act on local features
            row = {**time_production(big, frames), "thickness_mm": config.thickness_mm, "half_angle_deg": config.half_angle_deg}
            row["element_ratio"] = big.mesh.n_tets / model.mesh.n_tets
            row["cost_ratio"] = row["ms_per_frame_median"] / result["production"]["ms_per_frame_median"]
            compiled = time_production(replace(compiled_model, path=None, mesh=mesh, graph=big.graph), frames)
            row["compiled_ms_per_frame_median"] = compiled["ms_per_frame_median"]
            row["compiled_cost_ratio"] = compiled["ms_per_frame_median"] / result["production_compiled"]["ms_per_frame_median"]
            result["larger_mesh"][name] = row
    return result


def _four_times_area(half_angle_deg: float) -> float:
    """Half-angle of a spherical cap with 4× the area of one with ``half_angle_deg`` (area ∝ 1 − cos)."""
    return float(np.degrees(np.arccos(1.0 - 4.0 * (1.0 - np.cos(np.radians(half_angle_deg))))))


#: the whole socket's element sizes the socket model's step is timed at (the frontier toward the solver's 0.45 mm)
SOCKET_ELEMENT_SIZES_MM = (1.5, 1.0)


#: the pushed chain the socket bench reams on the whole default socket: reamer sizes (mm) one after
#: another, each for the bench's frames, at the trainer's largest push (N)
SOCKET_BENCH_REAMERS_MM = (48.0, 50.0)
SOCKET_BENCH_PUSH_N = 310.0


def time_socket_steps(
    model: LoadedModel | None,
    frames: int = 40,
    element_sizes_mm: tuple[float, ...] = SOCKET_ELEMENT_SIZES_MM,
    compile: bool = False,
) -> list[dict]:
    """ms per step of a socket model (``model``; None: untrained socket weights) on the whole default
    socket at each element size: tool-forced, the reamer reamed straight in along the socket's axis
    at 3 mm/s one size up (so every size times the same path; the first five steps left out as
    warm-up), and pushed, as a trainee reams (a model with a reaction head): each reamer of
    :data:`SOCKET_BENCH_REAMERS_MM` ``frames`` frames at :data:`SOCKET_BENCH_PUSH_N`, every step
    counted, a new reamer's start and its approach in free air included; with ``compile`` the pushed
    chain again with the network compiled, as ``thrsim serve`` runs it (``pushed_compiled``)."""
    from thrsim.config import SocketConfig
    from thrsim.geometry.socket import generate_socket

    socket = SocketConfig()
    reamer_mm = socket.socket_diameter_mm + 2.0
    axis = np.array([0.0, 0.0, -1.0])
    rows = []
    compiled_model: LoadedModel | None = None
    for size in element_sizes_mm:
        started = time.perf_counter()
        mesh = generate_socket(socket.model_copy(update={"element_size_mm": size}))
        meshing_s = time.perf_counter() - started
        used = model if model is not None else untrained_model(mesh, preset("socket"), teeth_radius_m=reamer_mm * 0.5e-3)
        if model is None:
            used.card["reamer"]["sizes_mm"] = [reamer_mm]
        simulator = ReamingSimulator(model=used, mesh=mesh)
        start = simulator.reamer_start(axis)
        times, regions = [], []
        for k in range(frames + 5):
            result = simulator.step(axis, PUSH_FORCE_N, reamer_position=start + axis * (3e-3 * k / 60.0), reamer_mm=reamer_mm)
            times.append(result.seconds * 1e3)
            regions.append(simulator._step.last.region)
        steps = np.array(times[5:])
        row: dict[str, object] = {
            "element_size_mm": size, "elements": mesh.n_tets, "meshing_s": meshing_s, "reamer_mm": reamer_mm,
            "step_ms_median": float(np.median(steps)), "step_ms_max": float(steps.max()),
            "frames_per_s_median": 1e3 / float(np.median(steps)), "region_elements_max": int(max(regions)),
            "weights": "trained" if model is not None else "initial",
        }  # fmt: skip
        if used.settings.arch.reaction_head:
            row["pushed"] = _time_pushed_chain(simulator, axis, frames)
            if compile:
                if compiled_model is None:  # compiling changes the network in place; one copy serves every mesh
                    compiled_model = replace(used, gn=copy.deepcopy(used.gn))
                started = time.perf_counter()
                compiled = ReamingSimulator(model=compiled_model, mesh=mesh, compile=True)
                row["pushed_compiled"] = _time_pushed_chain(compiled, axis, frames) | {
                    "network": "compiled" if compiled.compiled else "eager",
                    "compile_s": time.perf_counter() - started,
                    "compile_error": compiled.compile_error,
                }
        rows.append(row)
    return rows


def _time_pushed_chain(simulator: ReamingSimulator, axis: np.ndarray, frames: int) -> dict:
    """Every step of :data:`SOCKET_BENCH_REAMERS_MM` one after another, ``frames`` frames each at
    :data:`SOCKET_BENCH_PUSH_N`, from intact bone."""
    simulator.reset()
    pushed = []
    for reamer in SOCKET_BENCH_REAMERS_MM:
        simulator.withdraw()
        pushed += [simulator.step(axis, SOCKET_BENCH_PUSH_N, reamer_mm=reamer).seconds * 1e3 for _ in range(frames)]
    ms = np.array(pushed)
    return {
        "reamers_mm": list(SOCKET_BENCH_REAMERS_MM), "push_n": SOCKET_BENCH_PUSH_N, "frames": len(ms),
        "step_ms_median": float(np.median(ms)), "step_ms_p99": float(np.percentile(ms, 99)), "step_ms_max": float(ms.max()),
        "frames_per_s_worst": 1e3 / float(ms.max()), "depth_mm": simulator.depth_m * 1e3,
        "removed_volume_mm3": simulator.removed_volume_m3 * 1e9,
    }  # fmt: skip
