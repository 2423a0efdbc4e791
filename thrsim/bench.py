"""Performance figures (``thrsim bench``): timed on the default 0.45 mm mesh unless told otherwise.

Speed targets live here, never in unit tests. Each figure records what it measured so a
number read later can be compared like with like.
"""

from __future__ import annotations

import os
import platform
import time

import numba

from thrsim.config import BonePatchConfig, ReamingCaseConfig
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.physics.reaming import CONTACT_STEPS, ReamingSimulation
from thrsim.provenance import package_versions


def bench_mesh(bone: BonePatchConfig) -> dict:
    started = time.perf_counter()
    mesh = generate_bone_patch(bone)
    seconds = time.perf_counter() - started
    started = time.perf_counter()
    adjacency = mesh.adjacency
    return {
        "elements": mesh.n_tets,
        "mesh_seconds": seconds,
        "adjacency_seconds": time.perf_counter() - started,
        "edges": int(len(adjacency.pairs)),
    }


def bench_solver(bone: BonePatchConfig, frames: int, inclination_deg: float = 15.0, anteversion_deg: float = 30.0) -> dict:
    """Seconds per output frame of the default reaming case (after one warm-up frame: JIT compile)."""
    case = ReamingCaseConfig(inclination_deg=inclination_deg, anteversion_deg=anteversion_deg, frames=frames + 1, bone=bone)
    simulation = ReamingSimulation(case)
    simulation.run(1)
    started = time.perf_counter()
    for _ in range(frames):
        simulation.start_frame_statistics()
        simulation.advance(simulation.steps_per_frame)
    seconds = (time.perf_counter() - started) / frames
    return {
        "case": f"inclination {inclination_deg} deg, anteversion {anteversion_deg} deg, {case.force_n:g} N",
        "elements": simulation.mesh.n_tets,
        "frames_timed": frames,
        "seconds_per_frame": seconds,
        "ms_per_step": 1e3 * seconds / simulation.steps_per_frame,
        "steps_per_frame": simulation.steps_per_frame,
        "dt_s": simulation.solid.dt,
        "removed_after": int((simulation.solid.active == 0).sum()),
        "contact_omega_dt": simulation.contact_omega_dt,
        "last_frame_contact_fraction": simulation.frame_stats[CONTACT_STEPS] / simulation.steps_per_frame,
        "thesis_abaqus_seconds_per_frame": 105.0,
    }


def run_benchmarks(element_size_mm: float = 0.45, frames: int = 3) -> dict:
    bone = BonePatchConfig(element_size_mm=element_size_mm)
    return {
        "machine": {
            "cpu_count": os.cpu_count(),
            "numba_threads": numba.get_num_threads(),
            "platform": platform.platform(),
        },
        "versions": package_versions(),
        "mesh": bench_mesh(bone),
        "solver": bench_solver(bone, frames),
    }
