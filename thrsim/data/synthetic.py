"""A small deterministic stand-in for the FEM solver, with :func:`thrsim.data.ground_truth.run_case`'s signature.

It exists for tests and demonstrations of the data pipeline (sweeps, executors, resume, labels,
readers) without the cost of the explicit solver: a structured tet block under the reamer, a
reamer advancing along its axis D, PEEQ growing and elements removed where the reamer head
overlaps them. Nothing in it is physics; the case files it writes follow the case-file layout (:mod:`thrsim.data.case_file`) exactly and
carry ``attrs["solver"] = "synthetic"``.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from thrsim.config import PUSH_FORCE_N, ReamingCaseConfig
from thrsim.data.case_file import CaseFrames, write_case
from thrsim.geometry.mesh import TetMesh

# the six tets of a cube's Kuhn subdivision (corner index = x + 2 y + 4 z)
_KUHN = np.array([[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7], [0, 5, 1, 7]])


def block_mesh(n: int = 4, size_m: float = 4e-3, depth_m: float = 2e-3, z0_m: float = -22e-3) -> TetMesh:
    """A structured n × n × max(1, n/2) block of tets below z0 (the articular face at z = z0)."""
    nz = max(1, n // 2)
    xs = np.linspace(-size_m / 2, size_m / 2, n + 1)
    zs = np.linspace(z0_m - depth_m, z0_m, nz + 1)
    gx, gy, gz = np.meshgrid(xs, xs, zs, indexing="ij")
    nodes = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)

    def nid(i, j, k):
        return (i * (n + 1) + j) * (nz + 1) + k

    tets: list[list[int]] = []
    for i in range(n):
        for j in range(n):
            for k in range(nz):
                corners = [nid(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)) for c in range(8)]
                tets.extend([[corners[c] for c in tet] for tet in _KUHN])
    tet_array = np.array(tets, dtype=np.int64)
    a, b, c, d = (nodes[tet_array[:, m]] for m in range(4))
    vol = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)
    flip = vol < 0
    tet_array[flip] = tet_array[flip][:, [0, 2, 1, 3]]
    fixed = np.flatnonzero(np.isclose(nodes[:, 2], zs[0]))
    inner = np.flatnonzero(np.isclose(nodes[:, 2], zs[-1]))
    return TetMesh(nodes=nodes, tets=tet_array, node_sets={"outer": fixed, "inner": inner}, fixed_nodes=fixed)


def synthetic_run_case(
    case: ReamingCaseConfig,
    out: Path,
    progress: Callable[[int, int], None] | None = None,
    *,
    seconds_per_frame: float = 0.0,
) -> dict:
    """Write a deterministic synthetic case to ``out``; return a summary like the solver's."""
    started = time.perf_counter()
    if not seconds_per_frame:  # lets subprocess tests slow the stand-in down
        seconds_per_frame = float(os.environ.get("THRSIM_SYNTHETIC_SECONDS_PER_FRAME", "0") or 0)
    n = max(2, min(12, int(round(4.0 / max(case.bone.element_size_mm, 0.1)))))
    mesh = block_mesh(n=n)
    axis = np.array(case.orientation.reamer_axis)
    t_frames = case.frames
    radius = 3e-3
    speed = 2e-4 * case.force_n / PUSH_FORCE_N  # m per frame
    start = np.array([0.0, 0.0, -22e-3]) - axis * radius  # head touching the face at frame 0
    centroids = mesh.centroids
    status = np.ones((t_frames, mesh.n_tets), dtype=np.uint8)
    peeq = np.zeros((t_frames, mesh.n_tets), dtype=np.float32)
    vm = np.zeros((t_frames, mesh.n_tets), dtype=np.float32)
    position = np.zeros((t_frames, 3))
    energy = np.zeros((t_frames, 4))
    # energies of the reamer's motion, so the summary's kinetic ÷ internal comes from the frames
    head_mass_kg = case.reamer.density_kg_m3 * (2 * math.pi / 3) * case.reamer.head_radius**3
    kinetic_j = 0.5 * head_mass_kg * (speed / case.frame_dt_s) ** 2
    # a stand-in reaction: a share per element in the head's reach that was bone, more at a faster feed
    reaction = np.zeros(t_frames)
    for t in range(t_frames):
        position[t] = start + axis * speed * t
        if t > 0:
            engaged = int(((np.linalg.norm(centroids - position[t], axis=1) < radius) & (status[t - 1] == 1)).sum())
            reaction[t] = 0.5 * engaged * (1.0 + speed / 2e-4)
            depth = radius - np.linalg.norm(centroids - position[t], axis=1)
            grow = np.clip(depth / 5e-4, 0.0, None).astype(np.float32) * 0.2
            peeq[t] = peeq[t - 1] + grow
            status[t] = status[t - 1] & (peeq[t] < 0.6)
            vm[t] = np.where(status[t] == 1, 2e7 * np.exp(-np.clip(-depth, 0, None) / 1e-3) * (1 + 0.1 * math.cos(t)), 0.0)
        work_j = case.force_n * speed * t  # push force × advance
        energy[t] = [kinetic_j if t > 0 else 0.0, 0.5 * work_j, 1e-3 * float(peeq[t].sum()), 0.1 * work_j]
        if progress is not None:
            progress(t + 1, t_frames)
        if seconds_per_frame:
            time.sleep(seconds_per_frame)
    frames = CaseFrames(
        time=np.arange(t_frames) * case.frame_dt_s,
        status=status,
        peeq=peeq,
        von_mises=vm,
        reamer_position=position,
        energy=energy,
        energy_names=("kinetic", "internal", "plastic_dissipation", "contact"),
        contact_force=np.tile(-axis * case.force_n, (t_frames, 1)),
        contact_force_axial=reaction,
        motor_torque=1e-3 * reaction,
        # as the solver records them: damage reaches 1 where an element goes (PEEQ 0.6 here)
        damage=np.clip(peeq / 0.6, 0.0, 1.0).astype(np.float32),
        damage_initiation=np.clip(peeq / 0.3, 0.0, 1.0).astype(np.float32),
    )
    removed = int(mesh.n_tets - status[-1].sum())
    moving = energy[1:, 1] > 0
    kinetic_to_internal = float(np.max(energy[1:, 0][moving] / energy[1:, 1][moving])) if moving.any() else 0.0
    wall = time.perf_counter() - started
    write_case(
        out,
        mesh,
        frames,
        axis,
        inclination_deg=case.inclination_deg,
        anteversion_deg=case.anteversion_deg,
        force_n=case.force_n,
        omega_rad_s=case.reamer.omega_rad_s,
        frame_dt_s=case.frame_dt_s,
        config=case.model_dump(mode="json"),
        extra_attrs={"solver": "synthetic", "end_reason": "completed", "seconds_per_frame": wall / t_frames},
    )
    return {
        "frames": t_frames,
        "removed": removed,
        "seconds_per_frame": wall / t_frames,
        "max_kinetic_to_internal": kinetic_to_internal,
        "end_reason": "completed",
        "solver": "synthetic",
    }
