"""Performance figures (``thrsim bench``): timed on the default 0.45 mm mesh unless told otherwise.

Speed targets live here, never in unit tests. Each figure records what it measured so a
number read later can be compared like with like.
"""

from __future__ import annotations

import os
import platform
import time

import numba
import numpy as np

from thrsim.config import PUSH_FORCE_N, BonePatchConfig, ReamingCaseConfig, SocketConfig, head_diameter_for_size
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.physics.reaming_case import CONTACT_STEPS, ReamingCase
from thrsim.provenance import package_versions
from thrsim.verification.reaming_checks import socket_window_case

#: the whole socket's element size in the benchmark: coarse enough for a frame in minutes on two cores
WHOLE_SOCKET_ELEMENT_MM = 1.5


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


def _time_frames(simulation: ReamingCase, frames: int) -> dict:
    """Time ``frames`` frames after one warm-up frame (JIT compile, first contact); the cost per active
    element and step is what compares a patch with a socket whatever their sizes."""
    simulation.run(1)
    zone_choices = len(simulation.zone_sizes)
    started = time.perf_counter()
    for _ in range(frames):
        simulation.start_frame_statistics()
        simulation.advance_frame()
    seconds = (time.perf_counter() - started) / frames
    timed_zones = simulation.zone_sizes[zone_choices:]
    active = float(np.median(timed_zones)) if timed_zones else float((simulation.solid.active > 0).sum())
    return {
        "elements": simulation.mesh.n_tets,
        "active_elements_median": active,
        "frames_timed": frames,
        "seconds_per_frame": seconds,
        "ms_per_step": 1e3 * seconds / simulation.steps_per_frame,
        "ns_per_active_element_step": 1e9 * seconds / simulation.steps_per_frame / max(active, 1.0),
    }


def bench_socket(frames: int) -> dict:
    """The socket's cost against its active elements: a window reamed at a set feed (a 0.5 dataset case)
    and the whole socket at a coarse size, each against the patch's cost per active element."""
    base = ReamingCaseConfig(inclination_deg=0.0, anteversion_deg=0.0)
    reamer = base.reamer.model_copy(update={"head_diameter_mm": head_diameter_for_size(48.0)})
    window = socket_window_case(frames + 1)  # the verified window case, the 0.5 dataset's kind
    whole = base.model_copy(
        update={
            "bone_kind": "socket",
            "frames": frames + 1,
            "reamer": reamer,
            "socket": SocketConfig(element_size_mm=WHOLE_SOCKET_ELEMENT_MM),
        }
    )
    return {
        "window": {
            "case": "48 mm reamer on the native 46 mm socket, window 30°/90°, feed 1 mm/s",
            **_time_frames(ReamingCase(window), frames),
        },
        "whole": {
            "case": f"48 mm reamer on the native 46 mm socket at {WHOLE_SOCKET_ELEMENT_MM} mm elements, {PUSH_FORCE_N:g} N along the socket axis",
            **_time_frames(ReamingCase(whole), frames),
        },
    }


def bench_solver(bone: BonePatchConfig, frames: int, inclination_deg: float = 15.0, anteversion_deg: float = 30.0) -> dict:
    """Seconds per output frame of the default reaming case (after one warm-up frame: JIT compile)."""
    case = ReamingCaseConfig(inclination_deg=inclination_deg, anteversion_deg=anteversion_deg, frames=frames + 1, bone=bone)
    simulation = ReamingCase(case)
    timed = _time_frames(simulation, frames)
    return {
        "case": f"inclination {inclination_deg} deg, anteversion {anteversion_deg} deg, {case.force_n:g} N",
        **timed,
        "steps_per_frame": simulation.steps_per_frame,
        "dt_s": simulation.solid.dt,
        "removed_after": int((simulation.solid.active == 0).sum()),
        "contact_omega_dt": simulation.contact_omega_dt,
        "last_frame_contact_fraction": simulation.frame_stats[CONTACT_STEPS] / simulation.steps_per_frame,
        "thesis_abaqus_seconds_per_frame": 105.0,
    }


def run_benchmarks(element_size_mm: float = 0.45, frames: int = 3, socket: bool = False) -> dict:
    bone = BonePatchConfig(element_size_mm=element_size_mm)
    result = {
        "machine": {
            "cpu_count": os.cpu_count(),
            "numba_threads": numba.get_num_threads(),
            "platform": platform.platform(),
        },
        "versions": package_versions(),
        "mesh": bench_mesh(bone),
        "solver": bench_solver(bone, frames),
    }
    if socket:
        result["socket"] = bench_socket(frames)
        patch = result["solver"]["ns_per_active_element_step"]
        for figures in result["socket"].values():
            figures["cost_per_active_element_vs_patch"] = figures["ns_per_active_element_step"] / patch
    return result
