"""The ground-truth reaming case: a rigid spinning reamer pushed into the bone patch.

Set-up [5.3]: the bone patch's fixed nodes are held (encastre); the reamer spins at ω about its
axis D, has one translational degree of freedom s along D (its centre is c = s·D in the bone
frame), and is pushed by the surgeon's force along D plus gravity. Gravity acts along −z of
the bone frame (patient in lateral decubitus: the acetabulum opens upward), so only its
component m·g·(−z·D) along the axis matters. The reamer's axial motion is integrated with the
same central-difference step from push, gravity and the contact reaction, so it advances as
bone is removed.

Start: the reamer sits on its axis, backed off until its teeth clear every bone node by
``INITIAL_GAP_M``; frame 0 records the intact bone at t = 0. A case of N frames simulates
N/frame_rate seconds and records N + 1 frames (fewer if it ends early).

End reasons: ``completed``; ``perforated`` at the first frame in which nothing touched the
reamer and its teeth reach past the outer face of the shell. That frame is not recorded
(a reamer falling freely through the hole would teach the learned simulator nothing), so a
case perforated at frame k holds frames 0 … k − 1.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from thrsim.config import ReamingCaseConfig
from thrsim.errors import SimulationError
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.geometry.mesh import SIDE, TetMesh
from thrsim.geometry.reamer import build_reamer, frame_rotation
from thrsim.physics.contact import reamer_contact, spun_basis
from thrsim.physics.explicit import ExplicitSolid
from thrsim.physics.support import foundation_stiffness

INITIAL_GAP_M = 5e-5
ENERGY_NAMES = (
    "kinetic",
    "internal",
    "elastic",
    "plastic_dissipation",
    "damage_dissipation",
    "contact_work",
    "push_work",
    "reamer_kinetic",
    "debris_kinetic",
)
GRAVITY_DIRECTION = np.array([0.0, 0.0, -1.0])


@dataclass
class FrameLog:
    """Per-frame records accumulated in memory (a 20k-tet, 121-frame case is ~25 MB)."""

    time: list = field(default_factory=list)
    status: list = field(default_factory=list)
    peeq: list = field(default_factory=list)
    von_mises: list = field(default_factory=list)
    reamer_position: list = field(default_factory=list)
    energy: list = field(default_factory=list)
    contact_force: list = field(default_factory=list)


class ReamingSimulation:
    """Bone solid + rigid reamer, advanced frame by frame."""

    def __init__(self, case: ReamingCaseConfig, mesh: TetMesh | None = None) -> None:
        if case.solver.threads:
            numba.set_num_threads(min(case.solver.threads, numba.config.NUMBA_NUM_THREADS))
        self.case = case
        self.mesh = mesh if mesh is not None else generate_bone_patch(case.bone)
        side = self.mesh.node_sets.get(SIDE)
        springs = (
            foundation_stiffness(self.mesh, side, case.material.youngs_modulus_pa, case.bone.element_size_mm * 1e-3)
            if case.bone.support_side_faces and side is not None
            else None
        )
        self.solid = ExplicitSolid(
            self.mesh, case.material, case.hardening, case.damage, case.solver.target_dt_s, case.solver.safety_factor,
            support_stiffness=springs,
        )
        self.reamer = build_reamer(case.reamer)
        self.axis = np.array(case.orientation.reamer_axis)
        self.rotation = frame_rotation(self.axis)
        self.omega = case.reamer.omega_rad_s
        self.tooth_cos = np.cos(self.reamer.tooth_azimuth)
        self.tooth_sin = np.sin(self.reamer.tooth_azimuth)
        self.mass = self.reamer.mass_kg
        self.force_n = case.force_n  # the surgeon's push; may change during a run
        self.gravity_load = self.mass * case.reamer.gravity_m_s2 * float(GRAVITY_DIRECTION @ self.axis)
        self.position = self._initial_position()
        self.start_position = self.position
        self.speed = 0.0
        self.contact_force = np.zeros((self.mesh.n_nodes, 3))
        self.contact_work = 0.0
        self.push_work = 0.0
        self.outer_radius = case.bone.outer_radius
        self.steps_per_frame = max(1, round(case.frame_dt_s / self.solid.dt))
        self.first_contact_frame: int | None = None
        self.perforated_frame: int | None = None

    def _initial_position(self) -> float:
        """Axial coordinate s where the teeth clear the nearest bone node by the initial gap."""
        nodes = self.mesh.nodes
        reach = self.reamer.outer_radius + INITIAL_GAP_M

        def clearance(s: float) -> float:
            return float(np.linalg.norm(nodes - s * self.axis, axis=1).min()) - reach

        lo, hi = -2.0 * reach, 0.0
        if clearance(lo) <= 0:
            raise SimulationError("the reamer cannot be placed clear of the bone")
        if clearance(hi) > 0:
            lo = hi
            while clearance(hi) > 0:
                hi += 0.25 * reach
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if clearance(mid) > 0 else (lo, mid)
        return lo

    @property
    def centre(self) -> np.ndarray:
        return self.position * self.axis

    def step(self) -> tuple[np.ndarray, int]:
        """One step of bone and reamer; returns the total contact force on the bone and contacts."""
        solid = self.solid
        e1, e2 = spun_basis(self.rotation, self.omega * solid.time)
        contacts = reamer_contact(
            solid.positions, solid.velocity, solid.alive_nodes, solid.nodal_mass, self.centre, e1, e2, self.axis,
            self.speed, self.omega, self.reamer.head_radius, self.reamer.edge_axis_radius, self.reamer.edge_radius,
            self.tooth_cos, self.tooth_sin, self.reamer.tooth_polar_start, self.reamer.tooth_polar_end,
            self.case.contact.penalty_stiffness_n_m, self.case.contact.damping_ratio, self.case.contact.friction,
            self.contact_force,
        )  # fmt: skip
        on_bone = self.contact_force.sum(axis=0)
        power = float(np.einsum("ij,ij->", self.contact_force, solid.velocity))
        solid.step(self.contact_force)
        # reamer: m·s̈ = push + gravity·D − (force on bone)·D
        acceleration = (self.force_n + self.gravity_load - float(on_bone @ self.axis)) / self.mass
        self.speed += solid.dt * acceleration
        advance = solid.dt * self.speed
        self.position += advance
        self.contact_work += power * solid.dt
        self.push_work += self.force_n * advance
        return on_bone, contacts

    def record(self, log: FrameLog, mean_force: np.ndarray) -> None:
        solid = self.solid
        kinetic, elastic = solid.kinetic_energy(), solid.elastic_energy()
        plastic, damage = solid.plastic_dissipation(), solid.damage_dissipation()
        log.time.append(solid.time)
        log.status.append(solid.active.copy())
        log.peeq.append(solid.peeq.astype(np.float32))
        log.von_mises.append(solid.von_mises().astype(np.float32))
        log.reamer_position.append(self.centre.copy())
        log.contact_force.append(mean_force.copy())
        log.energy.append(
            [kinetic, elastic + plastic + damage, elastic, plastic, damage, self.contact_work, self.push_work,
             0.5 * self.mass * self.speed**2, solid.deleted_kinetic_energy]
        )  # fmt: skip

    def _check(self, frame: int) -> None:
        solid = self.solid
        if not (np.isfinite(solid.displacement).all() and np.isfinite(solid.velocity).all() and math.isfinite(self.position)):
            raise SimulationError(f"frame {frame}: non-finite displacement or velocity (the step is unstable)")
        kinetic = solid.kinetic_energy()
        if not math.isfinite(kinetic):
            raise SimulationError(f"frame {frame}: non-finite kinetic energy (the step is unstable)")
        budget = abs(self.contact_work) + abs(self.push_work) + 1e-9
        if kinetic > self.case.solver.energy_blowup_factor * budget:
            raise SimulationError(
                f"frame {frame}: energy explosion (bone kinetic energy {kinetic:.3g} J against {budget:.3g} J of work done)"
            )

    def perforated(self) -> bool:
        tip = self.centre + self.reamer.outer_radius * self.axis
        return float(np.linalg.norm(tip)) > self.outer_radius

    def run(self, frames: int, progress: Callable[[int, int], None] | None = None) -> tuple[FrameLog, dict]:
        log = FrameLog()
        self.record(log, np.zeros(3))
        end_reason = "completed"
        started = time.perf_counter()
        for frame in range(1, frames + 1):
            force_sum = np.zeros(3)
            contact_steps = 0
            for _ in range(self.steps_per_frame):
                on_bone, contacts = self.step()
                force_sum += on_bone
                contact_steps += contacts > 0
            self._check(frame)
            if contact_steps == 0 and self.first_contact_frame is not None and self.perforated():
                # a frame of free fall through the hole is not recorded
                end_reason = "perforated"
                self.perforated_frame = frame
                break
            self.solid.delete_detached()
            if contact_steps and self.first_contact_frame is None:
                self.first_contact_frame = frame
            self.record(log, force_sum / self.steps_per_frame)
            if progress:
                progress(frame, frames)
        elapsed = time.perf_counter() - started
        return log, self._summary(log, end_reason, elapsed)

    def _summary(self, log: FrameLog, end_reason: str, elapsed: float) -> dict:
        energy = np.array(log.energy)
        kinetic, internal = energy[:, 0], energy[:, 1]
        after = slice(self.first_contact_frame + 1, None) if self.first_contact_frame is not None else slice(0, 0)
        ratio = kinetic[after] / np.maximum(internal[after], 1e-300)
        status = np.array(log.status)
        removed = int((status[-1] == 0).sum())
        simulated = len(log.time) - 1
        axial = (np.array(log.reamer_position) @ self.axis) - self.start_position
        return {
            "frames": simulated,
            "requested_frames": self.case.frames,
            "end_reason": end_reason,
            "perforated_frame": self.perforated_frame,
            "first_contact_frame": self.first_contact_frame,
            "elements": self.mesh.n_tets,
            "removed": removed,
            "detached": self.solid.detached_count,
            "removed_volume_mm3": float(self.solid.volume[status[-1] == 0].sum() * 1e9),
            "mean_peeq_active": float(self.solid.peeq[status[-1] > 0].mean()),
            "reamer_advance_mm": float(axial[-1] * 1e3),
            "seconds_per_frame": elapsed / max(simulated, 1),
            "steps_per_frame": self.steps_per_frame,
            "dt_s": self.solid.dt,
            "max_kinetic_to_internal": float(ratio.max()) if ratio.size else None,
            "reamer_mass_kg": self.mass,
            **self.solid.scaling.as_dict(),
        }


def run_case(case: ReamingCaseConfig, out: Path | None, progress: Callable[[int, int], None] | None = None, mesh: TetMesh | None = None) -> dict:
    """Simulate one case and write its HDF5 file (SPEC §4) atomically; return the JSON summary."""
    simulation = ReamingSimulation(case, mesh)
    log, summary = simulation.run(case.frames, progress)
    if out is not None:
        from thrsim.data.case_file import CaseFrames, write_case

        frames = CaseFrames(
            time=np.array(log.time),
            status=np.array(log.status, dtype=np.uint8),
            peeq=np.array(log.peeq, dtype=np.float32),
            von_mises=np.array(log.von_mises, dtype=np.float32),
            reamer_position=np.array(log.reamer_position),
            energy=np.array(log.energy),
            energy_names=ENERGY_NAMES,
            contact_force=np.array(log.contact_force),
        )
        write_case(
            out, simulation.mesh, frames, simulation.axis,
            inclination_deg=case.inclination_deg, anteversion_deg=case.anteversion_deg, force_n=case.force_n,
            omega_rad_s=case.reamer.omega_rad_s, frame_dt_s=case.frame_dt_s, config=case.model_dump(mode="json"),
            extra_attrs=summary,
        )  # fmt: skip
        summary["out"] = str(out)
    return summary
