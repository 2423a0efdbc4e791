"""The ground-truth reaming case: a rigid spinning reamer pushed into the bone patch.

Set-up [5.3]: the bone's fixed nodes are held (encastre); the reamer spins at ω about its axis D
and has one translational degree of freedom s along D (centre c = c₀ + s·D), hand-held
(:class:`thrsim.config.ReamerHoldConfig`): the push and gravity drive an effective mass with an
axial damper, M·s̈ = F + G − F_contact·D − c·ṡ, integrated with the bone's step, so it advances
as bone is removed. The energy balance (ABAQUS's ETOTAL) is booked every step and recorded per
frame. The reamer starts ``INITIAL_GAP_M`` clear of the bone; frame 0 is the intact bone. A case
ends ``perforated``, ``passed_through``, ``stalled`` or ``completed``, checked at every frame end
after first contact, and the ending frame is not recorded (a reamer falling freely teaches the
learned simulator nothing). Terms, end rules and why: the docs' Physics page (Solver).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import NamedTuple

import numba
import numpy as np
from numba import njit

from thrsim import portable_math as pm
from thrsim.config import ReamingCaseConfig
from thrsim.errors import SimulationError, ThrsimInputError
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.geometry.mesh import CANCELLOUS, CORTICAL, SIDE, TetMesh
from thrsim.geometry.reamer import build_reamer, frame_rotation
from thrsim.geometry.reaming_path import INITIAL_GAP_M, along_axis, bone_in_path, breach_faces, breach_reason, clear_start, tip_exit_depth
from thrsim.geometry.socket import generate_socket
from thrsim.physics.contact import (
    ContactArrays,
    ContactLaw,
    ReamerPose,
    ReamerTeeth,
    contact_step_work,
    contact_totals,
    keep_previous_increment,
    reamer_contact,
)
from thrsim.physics.explicit import ExplicitSolid, Tissue, solid_step, tissues_of
from thrsim.physics.support import foundation_stiffness

#: frames after first contact spent seating the reamer, left out of the steady-reaming statistics
SEATING_FRAMES = 5
#: a case whose reamer neither removes bone nor moves for this many frames has stalled
STALL_FRAMES = 10
STALL_MOTION_M = 1e-6

# reamer state: [axial position s (m), axial speed ṡ (m/s)]
POSITION, SPEED = 0, 1
# cumulative energy ledger (J), updated every step
SPIN, CONTACT_ON_BONE, FRICTION, CONTACT_NORMAL, PUSH, GRAVITY, ARM_DAMPING, AXIAL_REACTION = range(8)
LEDGER_SIZE = 8
# within-frame statistics, reset every frame
SUM_POSITION, MIN_POSITION, MAX_POSITION, SUM_AXIAL_FORCE, CONTACT_STEPS, SUM_FX, SUM_FY, SUM_FZ, SUM_PUSH = range(9)
FRAME_STATS_SIZE = 9

#: the bone's state arrays (fields of SolidArrays) a checkpoint keeps; the rest is the mesh's, rebuilt
SOLID_STATE = (
    "active", "accounted", "stress", "peeq", "damage", "initiation", "plastic_work", "damage_work", "viscous_work",
    "viscous_pressure", "element_force", "nodal_mass", "inverse_mass", "elements_at_node", "velocity", "displacement", "du",
    "external_force", "cutting_damage", "debris",
)  # fmt: skip

ENERGY_NAMES = (
    "kinetic",
    "internal",
    "elastic",
    "plastic_dissipation",
    "damage_dissipation",
    "viscous_dissipation",
    "debris",
    "reamer_kinetic",
    "arm_damping",
    "contact_damping",
    "friction",
    "penalty",
    "push_work",
    "gravity_work",
    "spin_work",
    "external_work",
    "contact_work",
    "balance_error",
)
GRAVITY_DIRECTION = np.array([0.0, 0.0, -1.0])


class ReamerDrive(NamedTuple):
    """The hand-held reamer's axial loads: M·s̈ = push + gravity − F_contact·D − damping·ṡ (force
    control); or, with ``feed`` set (m/s, NaN: force control), the reamer advances at that rate and the
    push is whatever the bone's reaction takes: push = F_contact·D − gravity (a rig's feed, no arm)."""

    mass: float
    damping: float
    push: float
    gravity: float
    feed: float


@dataclass
class FrameLog:
    """Per-frame records accumulated in memory (a 20k-tet, 121-frame case is ~45 MB)."""

    time: list = field(default_factory=list)
    status: list = field(default_factory=list)
    peeq: list = field(default_factory=list)
    von_mises: list = field(default_factory=list)
    damage: list = field(default_factory=list)  # D: Johnson–Cook evolution plus the teeth's cutting
    damage_initiation: list = field(default_factory=list)  # ω: Johnson–Cook initiation (D grows once it reaches 1)
    reamer_position: list = field(default_factory=list)
    reamer_axial: list = field(default_factory=list)  # within-frame mean, min, max of s (m)
    contact_force_axial: list = field(default_factory=list)  # within-frame mean of F_contact·D (N)
    contact_fraction: list = field(default_factory=list)  # steps of the frame with any contact
    energy: list = field(default_factory=list)
    contact_force: list = field(default_factory=list)
    reaction_force: list = field(default_factory=list)  # within-frame mean of the bone's force on the reamer (N)
    push_force: list = field(default_factory=list)  # within-frame mean of the push along D (N): set, or what the feed takes
    motor_torque: list = field(default_factory=list)  # within-frame mean torque the motor delivers about D (N·m)

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> FrameLog:
        """The log that :meth:`arrays` gave (a checkpoint's frames read back)."""
        log = cls()
        for name, values in arrays.items():
            getattr(log, name).extend(np.asarray(values))
        return log

    def arrays(self) -> dict[str, np.ndarray]:
        """The records as arrays, in the case file's dtypes."""
        return {
            "time": np.array(self.time),
            "status": np.array(self.status, dtype=np.uint8),
            "peeq": np.array(self.peeq, dtype=np.float32),
            "von_mises": np.array(self.von_mises, dtype=np.float32),
            "damage": np.array(self.damage, dtype=np.float32),
            "damage_initiation": np.array(self.damage_initiation, dtype=np.float32),
            "reamer_position": np.array(self.reamer_position),
            "reamer_axial": np.array(self.reamer_axial),
            "contact_force_axial": np.array(self.contact_force_axial),
            "contact_fraction": np.array(self.contact_fraction),
            "energy": np.array(self.energy),
            "contact_force": np.array(self.contact_force),
            "reaction_force": np.array(self.reaction_force),
            "push_force": np.array(self.push_force),
            "motor_torque": np.array(self.motor_torque),
        }


@njit(cache=True)
def advance_reaming(
    steps, time, nodes, rotation, line_point, omega, solid, constants, teeth, law, contact, drive, reamer, ledger, stats, totals
):
    """The reaming loop, compiled: contact, solid step and the reamer's axial motion, ``steps`` times.

    ``solid``/``constants``: :class:`~thrsim.physics.explicit.SolidArrays` and
    :class:`~thrsim.physics.explicit.MaterialConstants`; ``teeth``/``law``/``contact``: see
    :mod:`thrsim.physics.contact` (``contact.force`` is the solid's external force);
    ``drive``: :class:`ReamerDrive`; ``reamer``: [s, ṡ]; ``ledger`` and ``stats`` are updated
    at the indices named in this module; ``totals`` is scratch. Returns the time reached.
    """
    dt = constants.dt
    axis = np.empty(3)
    centre = np.empty(3)
    e1 = np.empty(3)
    e2 = np.empty(3)
    for i in range(3):
        axis[i] = rotation[i, 2]
    for _ in range(steps):
        spin_cos, spin_sin = pm.cos(omega * time), pm.sin(omega * time)
        position, speed = reamer[POSITION], reamer[SPEED]
        for i in range(3):
            centre[i] = line_point[i] + position * axis[i]
            e1[i] = spin_cos * rotation[i, 0] + spin_sin * rotation[i, 1]
            e2[i] = -spin_sin * rotation[i, 0] + spin_cos * rotation[i, 1]
        pose = ReamerPose(centre, e1, e2, axis, speed, omega)
        contacts = reamer_contact(nodes, solid, pose, teeth, law, contact)
        contact_totals(contact, solid.contact_nodes, totals)
        axial_force = totals[0] * axis[0] + totals[1] * axis[1] + totals[2] * axis[2]
        keep_previous_increment(contact, solid.contact_nodes, solid.du)
        solid_step(solid, constants)
        if drive.feed == drive.feed:  # feed control: the advance is prescribed, the push follows
            damper = 0.0
            push = axial_force - drive.gravity
            reamer[SPEED] = drive.feed
        else:  # force control: M·s̈ = push + gravity − F_contact·D − c·ṡ, same central difference as the bone
            damper = drive.damping * speed
            push = drive.push
            reamer[SPEED] = speed + dt * (drive.push + drive.gravity - axial_force - damper) / drive.mass
        advance = dt * reamer[SPEED]
        reamer[POSITION] = position + advance
        ledger[PUSH] += push * advance
        ledger[GRAVITY] += drive.gravity * advance
        ledger[ARM_DAMPING] += damper * advance
        ledger[AXIAL_REACTION] += axial_force * advance
        contact_step_work(contact, solid.contact_nodes, solid.du, axis, speed, advance, dt, ledger)
        stats[SUM_POSITION] += reamer[POSITION]
        stats[MIN_POSITION] = min(stats[MIN_POSITION], reamer[POSITION])
        stats[MAX_POSITION] = max(stats[MAX_POSITION], reamer[POSITION])
        stats[SUM_AXIAL_FORCE] += axial_force
        stats[SUM_FX] += totals[0]
        stats[SUM_FY] += totals[1]
        stats[SUM_FZ] += totals[2]
        stats[SUM_PUSH] += push
        if contacts > 0:
            stats[CONTACT_STEPS] += 1.0
        time += dt
    return time


class ReamingCase:
    """Bone solid + rigid hand-held reamer, advanced frame by frame (physics only: no files)."""

    def __init__(self, case: ReamingCaseConfig, mesh: TetMesh | None = None, mass_scaling_dt_s: float | None = None) -> None:
        """``mass_scaling_dt_s``: scale the bone's mass for this step, not the case's (a convergence study's)."""
        if case.solver.threads:
            numba.set_num_threads(min(case.solver.threads, numba.config.NUMBA_NUM_THREADS))
        self.case = case
        self.mesh = mesh if mesh is not None else bone_mesh(case)
        side = self.mesh.node_sets.get(SIDE)
        springs = (
            foundation_stiffness(self.mesh, side, case.material.youngs_modulus_pa, case.bone.element_size_mm * 1e-3)
            if case.bone.support_side_faces and side is not None
            else None
        )
        cortical, others = case_tissues(case)
        self.solid = ExplicitSolid(
            self.mesh, cortical.material, cortical.hardening, cortical.damage, case.solver.target_dt_s, case.solver.safety_factor, support_stiffness=springs, other_tissues=others,
            mass_scaling_dt_s=mass_scaling_dt_s,
        )  # fmt: skip
        self.start_from_digest: str | None = None
        self.prepared = self._prepare(case)
        self.reamer = build_reamer(case.reamer)
        self.axis = np.array(case.orientation.reamer_axis)
        self.line_point = np.array(case.reamer_centre_mm, dtype=np.float64) * 1e-3
        self.rotation = frame_rotation(self.axis)
        self.omega = case.reamer.omega_rad_s
        self.teeth = ReamerTeeth(
            head_radius=self.reamer.head_radius, edge_axis_radius=self.reamer.edge_axis_radius,
            edge_radius=self.reamer.edge_radius, tooth_cos=pm.cos_array(self.reamer.tooth_azimuth),
            tooth_sin=pm.sin_array(self.reamer.tooth_azimuth), tooth_start=self.reamer.tooth_polar_start,
            tooth_end=self.reamer.tooth_polar_end,
        )  # fmt: skip
        self.contact_law = ContactLaw(
            case.contact.penalty_factor, case.contact.damping_ratio, case.contact.friction, self.solid.dt,
            cutting_energies(case, self.mesh),
        )  # fmt: skip
        # the kernels share the force and cutting arrays: contact writes them, the solid step reads them
        scratch = ContactArrays.zeros(self.mesh.n_nodes)
        self.contact = scratch._replace(force=self.solid.external_force, cutting_damage=self.solid.cutting_damage)
        self.mass = case.hold.effective_mass_kg
        self.force_n = case.force_n  # the surgeon's push; may change during a run
        self.gravity_load = self.reamer.mass_kg * case.reamer.gravity_m_s2 * float(along_axis(GRAVITY_DIRECTION, self.axis))
        self.start_position = self._initial_position()
        self.state = np.array([self.start_position, 0.0])
        self.ledger = np.zeros(LEDGER_SIZE)
        self.frame_stats = np.zeros(FRAME_STATS_SIZE)
        self._scratch = np.zeros(4)
        self.steps_per_frame = max(1, round(case.frame_dt_s / self.solid.dt))
        self._face_elements = breach_faces(self.mesh, self.prepared) if case.bone_kind == "socket" else {}
        self.tip_exit_depth = None if case.bone_kind == "socket" else tip_exit_depth(self.mesh, self.axis)
        self.spin_work_at_frame_start = 0.0
        self.zone_sizes: list[int] = []  # active elements integrated, at each choice of the zone
        self.first_contact_frame: int | None = None
        self.perforated_frame: int | None = None
        self.frames_done = 0  # frames recorded after frame 0
        self.log = FrameLog()

    def _prepare(self, case: ReamingCaseConfig) -> np.ndarray:
        """Ream the socket geometrically to ``pre_ream_mm`` (every element whose centroid lies in the
        sphere goes, then the chips it frees), or start from another case's last frame; the elements
        gone before the case starts."""
        if case.start_from is not None:
            self._carry_over(case.start_from)
            return self.solid.active == 0
        if case.pre_ream_mm is None:
            return np.zeros(self.mesh.n_tets, dtype=bool)
        centre = np.array(case.pre_ream_centre_mm) * 1e-3
        inside = np.linalg.norm(self.mesh.centroids - centre, axis=1) < 0.5e-3 * case.pre_ream_mm
        self.solid.remove_elements(inside)
        self.solid.delete_detached()
        self.solid.detached_count = 0
        self.solid.debris[:] = 0.0
        return self.solid.active == 0

    def _carry_over(self, path: str) -> None:
        """Take the bone of ``path``'s last frame: its removed elements stay removed, its damage, damage
        initiation and PEEQ carry on; stresses start at zero (the bone unloads while reamers change).
        A case from another mesh or another thrsim version is refused."""
        from thrsim import __version__
        from thrsim.data.case_file import CaseReader, file_sha256

        with CaseReader(path) as source:
            version = source.attrs.get("thrsim_version")
            if version != __version__:
                raise ThrsimInputError(f"{path}: written by thrsim {version}, not this thrsim {__version__}: its bone state may differ")
            mesh = source.mesh
            if mesh.n_tets != self.mesh.n_tets or not (
                np.array_equal(mesh.nodes, self.mesh.nodes) and np.array_equal(mesh.tets, self.mesh.tets)
            ):
                raise ThrsimInputError(f"{path}: its mesh is not this case's ({mesh.n_tets} elements against {self.mesh.n_tets})")
            last = source.frame(-1)
        removed = last["status"] == 0
        alive = ~removed
        self.solid.peeq[alive] = last["peeq"][alive]
        if "damage" in last:
            self.solid.damage[alive] = last["damage"][alive]
        if "damage_initiation" in last:
            self.solid.initiation[alive] = last["damage_initiation"][alive]
        self.solid.remove_elements(removed)
        self.start_from_digest = file_sha256(path)

    def breached(self) -> str | None:
        """For a socket: ``medial_wall_breached`` when an element on the medial wall's pelvic face has
        gone (a hole into the pelvis), ``perforated`` when one on the supported boundary has (through
        the bone elsewhere); None while both hold. The patch uses :meth:`perforated` instead."""
        return breach_reason(self._face_elements, self.solid.active != 0)

    @property
    def drive(self) -> ReamerDrive:
        feed = math.nan if self.case.feed_mm_s is None else self.case.feed_mm_s * 1e-3
        return ReamerDrive(self.mass, self.case.hold.axial_damping_n_s_m, float(self.force_n), self.gravity_load, feed)

    @property
    def contact_omega_dt(self) -> float:
        """ω·Δt of any node on its contact spring: √β by construction (k_i = β·m_i/Δt²)."""
        return math.sqrt(self.contact_law.penalty_factor)

    def _initial_position(self) -> float:
        """Axial coordinate s where the teeth clear the nearest bone node by the initial gap."""
        nodes = self.mesh.nodes[self.solid.alive_nodes]
        try:
            return clear_start(nodes, self.line_point, self.axis, self.reamer.outer_radius + INITIAL_GAP_M)
        except ValueError as error:
            raise SimulationError(str(error)) from None

    @property
    def centre(self) -> np.ndarray:
        return self.line_point + self.position * self.axis

    @property
    def position(self) -> float:
        """Axial coordinate s of the reamer centre along D (m)."""
        return float(self.state[POSITION])

    @property
    def speed(self) -> float:
        return float(self.state[SPEED])

    @property
    def zone_enabled(self) -> bool:
        setting = self.case.solver.active_zone
        return setting == "on" or (setting == "auto" and self.case.bone_kind == "socket")

    @property
    def zone_halo_m(self) -> float:
        """Bone integrated beyond the teeth's reach: the configured halo, and at least three elements."""
        element_mm = self.case.socket.element_size_mm if self.case.bone_kind == "socket" else self.case.bone.element_size_mm
        return max(self.case.solver.zone_halo_mm, 3.0 * element_mm) * 1e-3

    def select_zone(self, steps: int) -> int:
        """Choose the elements to integrate for the next ``steps`` steps: those with a node within the
        teeth's reach plus the halo of the segment the reamer's centre can sweep meanwhile (its travel
        at its current speed plus the lookahead, along D). Returns how many active elements it holds."""
        solver = self.case.solver
        travel = abs(self.speed) * steps * self.solid.dt + solver.zone_lookahead_mm * 1e-3
        relative = self.mesh.nodes + self.solid.displacement - self.centre
        along = np.clip(along_axis(relative, self.axis), 0.0, travel)
        lateral = relative - along[:, None] * self.axis
        near = (lateral * lateral).sum(axis=1) < (self.reamer.outer_radius + self.zone_halo_m) ** 2
        in_zone = near[self.mesh.tets].any(axis=1) & (self.solid.active > 0)
        touched = self.solid.set_zone(in_zone)
        idle = ~touched
        for array in (self.contact.force, self.contact.surface_velocity, self.contact.normal_force):
            array[idle] = 0.0
        self.contact.penalty_energy[idle] = 0.0
        self.contact.cutting_damage[idle] = 0.0
        return int(in_zone.sum())

    def advance_frame(self, part_done: Callable[[float], None] | None = None) -> None:
        """One frame of steps; with the active zone, the zone is chosen again every ``solver.zone_steps``
        and ``part_done`` told the share of the frame done after each choice but the last."""
        if not self.zone_enabled:
            self.advance(self.steps_per_frame)
            return
        done = 0
        while done < self.steps_per_frame:
            steps = min(self.case.solver.zone_steps, self.steps_per_frame - done)
            self.zone_sizes.append(self.select_zone(steps))
            self.advance(steps)
            done += steps
            if part_done is not None and done < self.steps_per_frame:
                part_done(done / self.steps_per_frame)

    def advance(self, steps: int) -> None:
        """Run ``steps`` steps of bone and reamer in one compiled loop (statistics accumulate in
        ``frame_stats`` until :meth:`start_frame_statistics` resets them)."""
        self.solid.time = advance_reaming(
            steps, self.solid.time, self.mesh.nodes, self.rotation, self.line_point, self.omega, self.solid.arrays, self.solid.constants,
            self.teeth, self.contact_law, self.contact, self.drive, self.state, self.ledger, self.frame_stats, self._scratch,
        )  # fmt: skip

    def start_frame_statistics(self) -> None:
        self.frame_stats[:] = 0.0
        self.frame_stats[MIN_POSITION] = np.inf
        self.frame_stats[MAX_POSITION] = -np.inf

    def step(self) -> None:
        """One step of bone and reamer."""
        self.advance(1)

    def energies(self) -> dict[str, float]:
        """The energy ledger now, by name (J); see the module's balance."""
        solid, ledger = self.solid, self.ledger
        elastic, plastic, damage = solid.elastic_energy(), solid.plastic_dissipation(), solid.damage_dissipation()
        terms = {
            "kinetic": solid.kinetic_energy(),
            "internal": elastic + plastic + damage,
            "elastic": elastic,
            "plastic_dissipation": plastic,
            "damage_dissipation": damage,
            "viscous_dissipation": solid.viscous_dissipation(),
            "debris": solid.deleted_kinetic_energy + solid.deleted_elastic_energy,
            "reamer_kinetic": 0.5 * self.mass * self.speed**2,
            "arm_damping": float(ledger[ARM_DAMPING]),
            "contact_damping": float(ledger[CONTACT_NORMAL]) - float(self._scratch[3]),
            "friction": float(ledger[FRICTION]),
            "penalty": float(self._scratch[3]),
            "push_work": float(ledger[PUSH]),
            "gravity_work": float(ledger[GRAVITY]),
            "spin_work": float(ledger[SPIN]),
        }
        terms["external_work"] = terms["push_work"] + terms["gravity_work"] + terms["spin_work"]
        terms["contact_work"] = float(ledger[CONTACT_ON_BONE])
        stored = (
            "kinetic",
            "internal",
            "viscous_dissipation",
            "debris",
            "reamer_kinetic",
            "arm_damping",
            "contact_damping",
            "friction",
            "penalty",
        )
        terms["balance_error"] = terms["external_work"] - sum(terms[name] for name in stored)
        return terms

    def balance_by_part(self) -> dict[str, float]:
        """The balance error split where it arises (J): the bone (contact work on it against what
        it holds and lost), the reamer (push and gravity against its motion, the arm and the
        contact reaction) and the contact interface (closed by construction, ~round-off)."""
        e = self.energies()
        reaction = float(self.ledger[AXIAL_REACTION])
        return {
            "bone": e["contact_work"] - (e["kinetic"] + e["internal"] + e["viscous_dissipation"] + e["debris"]),
            "reamer": e["push_work"] + e["gravity_work"] - reaction - e["arm_damping"] - e["reamer_kinetic"],
            "interface": e["spin_work"] + reaction - e["contact_work"] - e["friction"] - e["contact_damping"] - e["penalty"],
        }

    def record(self, log: FrameLog) -> None:
        solid, stats = self.solid, self.frame_stats
        log.time.append(solid.time)
        log.status.append(solid.active.copy())
        log.peeq.append(solid.peeq.astype(np.float32))
        log.von_mises.append(solid.von_mises().astype(np.float32))
        log.damage.append(solid.damage.astype(np.float32))
        log.damage_initiation.append(solid.initiation.astype(np.float32))
        log.reamer_position.append(self.centre.copy())
        energies = self.energies()
        log.energy.append([energies[name] for name in ENERGY_NAMES])
        if not log.reamer_axial:  # frame 0: the reamer at rest where it starts
            log.reamer_axial.append([self.position] * 3)
            log.contact_force_axial.append(0.0)
            log.contact_fraction.append(0.0)
            log.contact_force.append(np.zeros(3))
            log.reaction_force.append(np.zeros(3))
            log.push_force.append(0.0)
            log.motor_torque.append(0.0)
            return
        steps = self.steps_per_frame
        log.reamer_axial.append([stats[SUM_POSITION] / steps, stats[MIN_POSITION], stats[MAX_POSITION]])
        log.contact_force_axial.append(stats[SUM_AXIAL_FORCE] / steps)
        log.contact_fraction.append(stats[CONTACT_STEPS] / steps)
        contact_force = np.array([stats[SUM_FX], stats[SUM_FY], stats[SUM_FZ]]) / steps
        log.contact_force.append(contact_force)
        log.reaction_force.append(-contact_force)
        log.push_force.append(stats[SUM_PUSH] / steps)
        # the motor's power is the spin work over the frame; its torque about D, that power over ω
        spin_work = float(self.ledger[SPIN])
        frame_time = steps * self.solid.dt
        log.motor_torque.append((spin_work - self.spin_work_at_frame_start) / (self.omega * frame_time) if self.omega else 0.0)
        self.spin_work_at_frame_start = spin_work

    def check_stable(self, frame: int) -> None:
        """Raise :class:`SimulationError` if the state is not finite or the bone moves with more
        kinetic energy than ``solver.energy_blowup_factor`` × the work done on it (at most 1 × in truth)."""
        solid = self.solid
        if not (np.isfinite(solid.displacement).all() and np.isfinite(solid.velocity).all() and math.isfinite(self.position)):
            raise SimulationError(f"frame {frame}: non-finite displacement or velocity (the step is unstable)")
        kinetic = solid.kinetic_energy()
        if not math.isfinite(kinetic):
            raise SimulationError(f"frame {frame}: non-finite kinetic energy (the step is unstable)")
        budget = abs(self.ledger[PUSH]) + abs(self.ledger[SPIN]) + 1e-9
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
        return bone_in_path(self.mesh.nodes[alive] + self.solid.displacement[alive], self.centre, self.axis, self.reamer.outer_radius)

    def run(
        self, frames: int, progress: Callable[[float, int], None] | None = None, on_frame: Callable[[int], None] | None = None
    ) -> tuple[FrameLog, dict]:
        """Simulate up to ``frames`` frames (from where :meth:`restore` left it, else from frame 0);
        ``on_frame(k)`` runs after frame k is recorded (a checkpoint may be taken there), then
        ``progress(k, frames)``; within a frame ``progress`` gets the fraction done too (k − 1 + share,
        after each choice of the active zone: a whole-socket frame can take minutes)."""
        log = self.log
        if not log.time:
            self.record(log)
        end_reason = "completed"
        started = time.perf_counter()
        resumed_at = self.frames_done
        for frame in range(self.frames_done + 1, frames + 1):
            self.start_frame_statistics()
            self.advance_frame(None if progress is None else partial(_within_frame, progress, frame, frames))
            self.check_stable(frame)
            if self.first_contact_frame is not None:
                # a frame of free fall, through a hole or past the bone, is not recorded
                breach = self.breached()
                if breach is not None:
                    end_reason = breach
                    self.perforated_frame = frame
                    break
                if self.perforated():
                    end_reason = "perforated"
                    self.perforated_frame = frame
                    break
                if not self.bone_in_path():
                    end_reason = "passed_through"
                    break
            self.solid.delete_detached()
            if self.frame_stats[CONTACT_STEPS] > 0 and self.first_contact_frame is None:
                self.first_contact_frame = frame
            self.record(log)
            self.frames_done = frame
            if on_frame:
                on_frame(frame)
            if progress:
                progress(frame, frames)
            if self.first_contact_frame is not None and _stalled(log):
                end_reason = "stalled"
                break
        elapsed = time.perf_counter() - started
        summary = self._summary(log, end_reason, elapsed / max(self.frames_done - resumed_at, 1))
        summary["resumed_from_frame"] = resumed_at or None
        return log, summary

    def snapshot(self) -> dict[str, np.ndarray]:
        """Everything the frames after the last recorded one depend on, as named arrays: the bone's
        state, the reamer's, the ledgers and the frames recorded so far (a checkpoint's content)."""
        solid = self.solid
        arrays = {f"solid/{name}": getattr(solid.arrays, name) for name in SOLID_STATE}
        arrays |= {
            "solid/integrated": solid.integrated,
            "solid/scalars": np.array([solid.time, solid.detached_count], dtype=np.float64),
            "contact/surface_velocity": self.contact.surface_velocity,
            "contact/normal_force": self.contact.normal_force,
            "contact/penalty_energy": self.contact.penalty_energy,
            "reamer/state": self.state,
            "reamer/ledger": self.ledger,
            "reamer/scratch": self._scratch,
            "run/zone_sizes": np.array(self.zone_sizes, dtype=np.int64),
            "run/scalars": np.array(
                [self.frames_done, self.spin_work_at_frame_start, self.force_n, _or_minus_one(self.first_contact_frame)], dtype=np.float64
            ),
        }
        arrays |= {f"log/{name}": values for name, values in self.log.arrays().items()}
        return arrays

    def restore(self, arrays: dict[str, np.ndarray]) -> int:
        """Take the state a :meth:`snapshot` of this very case holds; returns the frame it was taken after."""
        solid = self.solid
        for name in SOLID_STATE:
            target = getattr(solid.arrays, name)
            target[...] = arrays[f"solid/{name}"]
        solid.integrated = np.array(arrays["solid/integrated"], dtype=bool)
        solid.time, detached = (float(v) for v in arrays["solid/scalars"])
        solid.detached_count = int(detached)
        for name in ("surface_velocity", "normal_force", "penalty_energy"):
            getattr(self.contact, name)[...] = arrays[f"contact/{name}"]
        self.state[...] = arrays["reamer/state"]
        self.ledger[...] = arrays["reamer/ledger"]
        self._scratch[...] = arrays["reamer/scratch"]
        self.zone_sizes = [int(v) for v in arrays["run/zone_sizes"]]
        frames_done, self.spin_work_at_frame_start, self.force_n, first_contact = (float(v) for v in arrays["run/scalars"])
        self.frames_done = int(frames_done)
        self.first_contact_frame = None if first_contact < 0 else int(first_contact)
        self.log = FrameLog.from_arrays({name[4:]: values for name, values in arrays.items() if name.startswith("log/")})
        return self.frames_done

    def _summary(self, log: FrameLog, end_reason: str, seconds_per_frame: float) -> dict:
        records = log.arrays()
        energy = records["energy"]
        names = {name: i for i, name in enumerate(ENERGY_NAMES)}
        kinetic, internal = energy[:, names["kinetic"]], energy[:, names["internal"]]
        after = slice(self.first_contact_frame + 1, None) if self.first_contact_frame is not None else slice(0, 0)
        ratio = kinetic[after] / np.maximum(internal[after], 1e-300)
        status = records["status"]
        removed_now = (status[-1] == 0) & ~self.prepared
        simulated = len(log.time) - 1
        axial = along_axis(records["reamer_position"] - self.line_point, self.axis) - self.start_position
        external = energy[-1, names["external_work"]]
        summary = {
            "frames": simulated,
            "requested_frames": self.case.frames,
            "end_reason": end_reason,
            "perforated_frame": self.perforated_frame,
            "first_contact_frame": self.first_contact_frame,
            "elements": self.mesh.n_tets,
            "prepared_removed": int(self.prepared.sum()),
            "active_zone": self.zone_enabled,
            "active_elements_median": int(np.median(self.zone_sizes)) if self.zone_sizes else int((self.solid.active > 0).sum()),
            "removed": int(removed_now.sum()),
            "detached": self.solid.detached_count,
            "removed_volume_mm3": float(self.solid.volume[removed_now].sum() * 1e9),
            "removed_volume_by_material_mm3": {
                name: float(self.solid.volume[removed_now & (self.mesh.element_material == index)].sum() * 1e9)
                for index, name in enumerate(self.mesh.material_names)
            },
            "bone": self.case.bone_kind,
            "reamer_diameter_mm": self.case.reamer.size_mm,
            "feed_mm_s": self.case.feed_mm_s,
            "push_mean_n": float(records["push_force"][after].mean()) if records["push_force"][after].size else None,
            "pre_ream_mm": self.case.pre_ream_mm,
            "start_from": self.start_from_digest,
            "reamer_teeth": self.reamer.tooth_count,
            "mean_peeq_active": float(self.solid.peeq[~removed_now].mean()) if (~removed_now).any() else None,
            "reamer_advance_mm": float(axial[-1] * 1e3),
            "seconds_per_frame": seconds_per_frame,
            "steps_per_frame": self.steps_per_frame,
            "dt_s": self.solid.dt,
            "max_kinetic_to_internal": float(ratio.max()) if ratio.size else None,
            "kinetic_to_internal_target": self.case.solver.max_kinetic_to_internal,
            "contact_omega_dt": self.contact_omega_dt,
            "reamer_effective_mass_kg": self.mass,
            "reamer_axial_damping_n_s_m": self.case.hold.axial_damping_n_s_m,
            "external_work_j": float(external),
            "energy_balance_error": float(abs(energy[-1, names["balance_error"]]) / external) if external > 0 else None,
            **steady_reaming_statistics(records, self.first_contact_frame, self.case.frame_dt_s, self.solid.volume),
            **self.solid.scaling.as_dict(),
        }
        return summary


def bone_mesh(case: ReamingCaseConfig) -> TetMesh:
    """The bone the case reams: the thesis's patch or the layered socket."""
    return generate_socket(case.socket) if case.bone_kind == "socket" else generate_bone_patch(case.bone)


def case_tissues(case: ReamingCaseConfig) -> tuple[Tissue, dict[str, Tissue]]:
    """The cortical tissue and the others by material name, from the case's settings."""
    cancellous = case.cancellous
    return Tissue(case.material, case.hardening, case.damage), {
        CANCELLOUS: Tissue(cancellous.material, cancellous.hardening, cancellous.damage, cancellous.compaction)
    }


def compacting_elements(case: ReamingCaseConfig, mesh: TetMesh) -> np.ndarray:
    """(E,) bool: the elements whose tissue is a crushable foam (crushed, it compacts and stays)."""
    cortical, others = case_tissues(case)
    compacts = np.array([tissue.compaction is not None for tissue in tissues_of(mesh, cortical, others)], dtype=bool)
    return compacts[mesh.element_material]


def cutting_energies(case: ReamingCaseConfig, mesh: TetMesh) -> np.ndarray:
    """The cutting law's specific energy u_c (J/m³) of each of the mesh's materials, in its tag order."""
    by_name = {CORTICAL: case.contact.specific_cutting_energy_j_m3, CANCELLOUS: case.cancellous.specific_cutting_energy_j_m3}
    cortical, others = case_tissues(case)
    tissues_of(mesh, cortical, others)  # refuses a material name with no constants
    return np.array([by_name[name] for name in mesh.material_names], dtype=np.float64)


def steady_reaming_statistics(
    records: dict[str, np.ndarray], first_contact_frame: int | None, frame_dt_s: float, volume: np.ndarray
) -> dict:
    """Within-frame excursion, contact fraction, feed and removal rates over the frames after seating.

    Steady frames are those from ``SEATING_FRAMES`` after first contact to the end; the rates
    are least-squares slopes over them (robust to the frame-to-frame scatter of a chaotic cut).
    """
    empty = {"steady_frames": 0, "excursion_median_mm": None, "excursion_p95_mm": None, "contact_fraction_mean": None,
             "feed_rate_mm_s": None, "removal_rate_mm3_s": None}  # fmt: skip
    if first_contact_frame is None:
        return empty
    start = first_contact_frame + SEATING_FRAMES
    axial = records["reamer_axial"][start:]
    if len(axial) < 2:
        return empty
    excursion = (axial[:, 2] - axial[:, 1]) * 1e3
    frames = np.arange(len(axial)) * frame_dt_s
    removed_volume = ((records["status"][start:] == 0) * volume).sum(axis=1) * 1e9
    return {
        "steady_frames": int(len(axial)),
        "excursion_median_mm": float(np.median(excursion)),
        "excursion_p95_mm": float(np.percentile(excursion, 95)),
        "contact_fraction_mean": float(records["contact_fraction"][start:].mean()),
        "feed_rate_mm_s": float(np.polyfit(frames, axial[:, 0] * 1e3, 1)[0]),
        "removal_rate_mm3_s": float(np.polyfit(frames, removed_volume, 1)[0]),
    }


def _stalled(log: FrameLog) -> bool:
    """No element removed and the mean axial position still over the last ``STALL_FRAMES`` frames."""
    if len(log.status) <= STALL_FRAMES:
        return False
    removed_then, removed_now = (log.status[-1 - STALL_FRAMES] == 0).sum(), (log.status[-1] == 0).sum()
    moved = abs(log.reamer_axial[-1][0] - log.reamer_axial[-1 - STALL_FRAMES][0])
    return bool(removed_now == removed_then and moved < STALL_MOTION_M)


def _or_minus_one(value: int | None) -> int:
    return -1 if value is None else value


def _within_frame(progress: Callable[[float, int], None], frame: int, frames: int, share: float) -> None:
    progress(frame - 1 + share, frames)
