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

End reasons, checked at the end of every frame after first contact:

* ``perforated``: the teeth's tip (the pole of the dome, c + R_teeth·D) has passed the outer
  face where there is bone under it, i.e. beyond the outermost outer-face node lying within
  one mean edge length of the reamer's axis line. The outer face is held, so the reamer can
  only get there through a hole it has cut, and from there it falls. A tilted reamer whose
  axis misses the patch (γ above the patch half-angle) has no bone under its tip and never
  perforates; its teeth passing the outer-face radius beside the patch is not a hole.
* ``passed_through``: no bone is left in the reamer's path (no attached node in front of the
  head's equatorial plane within the teeth's reach of the axis): a tilted reamer has swept
  through the patch and falls freely.
* ``completed``: all requested frames.

The ending frame is not recorded (a reamer falling freely teaches the learned simulator
nothing), so a case ended at frame k holds frames 0 … k − 1.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np
from numba import njit

from thrsim.config import ReamingCaseConfig
from thrsim.errors import SimulationError
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.geometry.mesh import SIDE, TetMesh
from thrsim.geometry.reamer import build_reamer, frame_rotation
from thrsim.geometry.tet_metrics import rms_edge_lengths
from thrsim.physics.contact import contact_totals, reamer_contact
from thrsim.physics.explicit import solid_step
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


@njit(cache=True)
def advance_reaming(
    steps, time, nodes, rotation, axis, omega, head_radius, edge_axis_radius, edge_radius,
    tooth_cos, tooth_sin, tooth_start, tooth_end, stiffness, damping_ratio, friction,
    mass, force_n, gravity_load, reamer_state, totals,
    tets, grads, volume, char_length, bulk_viscosity, active, du, dt,
    stress, peeq, damage, initiation, plastic_work, damage_work, element_force,
    lam, mu, a, b, n, c, rate0, d1, d2, d3, d4, u_f,
    accounted, element_mass, nodal_mass, elements_at_node, debris, offsets, entries,
    contact_force, support_stiffness, inverse_mass, held, velocity, displacement,
):  # fmt: skip
    """The reaming loop, compiled: contact, solid step and the reamer's axial motion per step.

    Reamer: m·s̈ = push + gravity·D − (contact force on the bone)·D, integrated with the same
    central-difference step as the bone. Returns the time reached.
    """
    centre = np.empty(3)
    e1 = np.empty(3)
    e2 = np.empty(3)
    for _ in range(steps):
        spin_cos, spin_sin = math.cos(omega * time), math.sin(omega * time)
        for i in range(3):
            centre[i] = reamer_state[0] * axis[i]
            e1[i] = spin_cos * rotation[i, 0] + spin_sin * rotation[i, 1]
            e2[i] = -spin_sin * rotation[i, 0] + spin_cos * rotation[i, 1]
        contacts = reamer_contact(
            nodes, displacement, velocity, inverse_mass, nodal_mass, centre, e1, e2, axis, reamer_state[1], omega,
            head_radius, edge_axis_radius, edge_radius, tooth_cos, tooth_sin, tooth_start, tooth_end,
            stiffness, damping_ratio, friction, contact_force,
        )  # fmt: skip
        fx, fy, fz, power = contact_totals(contact_force, velocity)
        solid_step(
            tets, grads, volume, char_length, bulk_viscosity, active, du, dt,
            stress, peeq, damage, initiation, plastic_work, damage_work, element_force,
            lam, mu, a, b, n, c, rate0, d1, d2, d3, d4, u_f,
            accounted, element_mass, nodal_mass, elements_at_node, debris,
            offsets, entries, contact_force, support_stiffness, inverse_mass, held, velocity, displacement,
        )  # fmt: skip
        acceleration = (force_n + gravity_load - (fx * axis[0] + fy * axis[1] + fz * axis[2])) / mass
        reamer_state[1] += dt * acceleration
        advance = dt * reamer_state[1]
        reamer_state[0] += advance
        reamer_state[2] += power * dt
        reamer_state[3] += force_n * advance
        totals[0] += fx
        totals[1] += fy
        totals[2] += fz
        if contacts > 0:
            totals[3] += 1.0
        time += dt
    return time


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
        self.start_position = self._initial_position()
        # [axial position s, axial speed ṡ, work of contact forces on the bone, work of the push]
        self.reamer_state = np.array([self.start_position, 0.0, 0.0, 0.0])
        self.contact_force = np.zeros((self.mesh.n_nodes, 3))
        self.steps_per_frame = max(1, round(case.frame_dt_s / self.solid.dt))
        self.tip_exit_depth = self._tip_exit_depth()
        self.first_contact_frame: int | None = None
        self.perforated_frame: int | None = None

    def _tip_exit_depth(self) -> float | None:
        """How far along D the outer face lies under the teeth's tip; None when no bone is under it.

        Bone is under the tip when outer-face nodes lie within one mean edge length of the axis
        line s·D; the outermost of them (largest x·D) is where the tip leaves the bone.
        """
        outer = self.mesh.fixed_nodes
        if len(outer) == 0:
            return None
        points = self.mesh.nodes[outer]
        along = points @ self.axis
        lateral = np.linalg.norm(points - along[:, None] * self.axis, axis=1)
        under_tip = lateral <= float(rms_edge_lengths(self.mesh.nodes, self.mesh.tets).mean())
        return float(along[under_tip].max()) if under_tip.any() else None

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

    @property
    def position(self) -> float:
        """Axial coordinate s of the reamer centre along D (m)."""
        return float(self.reamer_state[0])

    @property
    def speed(self) -> float:
        return float(self.reamer_state[1])

    @property
    def contact_work(self) -> float:
        return float(self.reamer_state[2])

    @property
    def push_work(self) -> float:
        return float(self.reamer_state[3])

    def advance(self, steps: int) -> tuple[np.ndarray, int]:
        """Run ``steps`` steps of bone and reamer in one compiled loop.

        Returns the sum over those steps of the contact force on the bone, and how many of the
        steps had any contact.
        """
        solid = self.solid
        contact = self.case.contact
        totals = np.zeros(4)  # Σ force on bone (3), steps with contact
        solid.time = advance_reaming(
            steps, solid.time, self.mesh.nodes, self.rotation, self.axis, self.omega,
            self.reamer.head_radius, self.reamer.edge_axis_radius, self.reamer.edge_radius,
            self.tooth_cos, self.tooth_sin, self.reamer.tooth_polar_start, self.reamer.tooth_polar_end,
            contact.penalty_stiffness_n_m, contact.damping_ratio, contact.friction,
            self.mass, self.force_n, self.gravity_load, self.reamer_state, totals,
            *solid.kernel_arguments(), self.contact_force, solid.support_stiffness, solid.inverse_mass,
            solid.held, solid.velocity, solid.displacement,
        )  # fmt: skip
        return totals[:3], int(totals[3])

    def step(self) -> tuple[np.ndarray, int]:
        """One step of bone and reamer; returns the contact force on the bone and whether it touched."""
        return self.advance(1)

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
        """The teeth's tip has passed the outer face where there is bone under it."""
        if self.tip_exit_depth is None:
            return False
        return self.position + self.reamer.outer_radius > self.tip_exit_depth

    def bone_in_path(self) -> bool:
        """Whether any attached node lies where the advancing dome can still meet it."""
        alive = self.solid.alive_nodes
        relative = self.mesh.nodes[alive] + self.solid.displacement[alive] - self.centre
        along = relative @ self.axis
        lateral_sq = np.einsum("ij,ij->i", relative, relative) - along**2
        return bool(np.any((along > 0.0) & (lateral_sq < self.reamer.outer_radius**2)))

    def run(self, frames: int, progress: Callable[[int, int], None] | None = None) -> tuple[FrameLog, dict]:
        log = FrameLog()
        self.record(log, np.zeros(3))
        end_reason = "completed"
        started = time.perf_counter()
        for frame in range(1, frames + 1):
            force_sum, contact_steps = self.advance(self.steps_per_frame)
            self._check(frame)
            if self.first_contact_frame is not None:
                # a frame of free fall, through a hole or past the bone, is not recorded
                if self.perforated():
                    end_reason = "perforated"
                    self.perforated_frame = frame
                    break
                if not self.bone_in_path():
                    end_reason = "passed_through"
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
            "mean_peeq_active": float(self.solid.peeq[status[-1] > 0].mean()) if (status[-1] > 0).any() else None,
            "reamer_advance_mm": float(axial[-1] * 1e3),
            "seconds_per_frame": elapsed / max(simulated, 1),
            "steps_per_frame": self.steps_per_frame,
            "dt_s": self.solid.dt,
            "max_kinetic_to_internal": float(ratio.max()) if ratio.size else None,
            "kinetic_to_internal_target": self.case.solver.max_kinetic_to_internal,
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
