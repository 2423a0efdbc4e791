"""Penalty contact between bone nodes and the rigid rotating reamer (head sphere + toothed ridges).

Written here: no library offers contact of a mesh against an analytic, spinning, toothed body.
Every node still attached to an active element is a candidate, interior ones included, so every
element can be cut [5.3.1]. The head is a sphere; a tooth is a ridge on it (round above its
edge's arc, flat flanks below it), of which the deepest acts, and head and tooth both push, at
right angles, on a node touching both. The stiffness is scaled to the step, k_i = β·m_i/Δt², so
contact can never drive the explicit step past its stability limit; friction is Coulomb's, capped
at what stops the slip in one step; and the friction work of a tooth cuts: it damages the node's
elements by W/Σ(u_c·V) (thrsim's sub-grid cutting law). Why each, and the stability bounds: the
docs' Physics page (Solver, Cutting law). The kernel also writes what the energy balance needs;
totals are summed sequentially (:func:`contact_totals`), so results never depend on the threads.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from thrsim import portable_math as pm
from thrsim.config import STICK_FRACTION


class ReamerTeeth(NamedTuple):
    """Rigid reamer geometry in its own frame (m, rad)."""

    head_radius: float
    edge_axis_radius: float
    edge_radius: float
    tooth_cos: np.ndarray  # cos ψ_k
    tooth_sin: np.ndarray
    tooth_start: np.ndarray  # polar angle where each edge starts
    tooth_end: np.ndarray


class ContactLaw(NamedTuple):
    penalty_factor: float  # β: k_i = β·m_i/Δt²
    damping_ratio: float  # ξ, fraction of critical for the node on its contact spring
    friction: float  # Coulomb μ
    dt: float
    cutting_energy: np.ndarray  # u_c per material row, J/m³: volume cut = tooth friction work / u_c


class ReamerPose(NamedTuple):
    """Where the reamer is this step: centre, spun basis, axis, axial speed, spin rate."""

    centre: np.ndarray  # (3,)
    e1: np.ndarray
    e2: np.ndarray
    axis: np.ndarray  # D
    axial_speed: float
    omega: float


class ContactArrays(NamedTuple):
    """Per-node contact output of one step."""

    force: np.ndarray  # (N, 3) on the bone, N
    surface_velocity: np.ndarray  # (N, 3) reamer surface velocity where the node touches
    normal_force: np.ndarray  # (N, 3) resultant normal force N on the bone (the force less friction), N
    penalty_energy: np.ndarray  # (N,) ½ k g², J
    cutting_damage: np.ndarray  # (N,) damage this step's tooth cutting adds to every active element at the node
    previous_du: np.ndarray  # (N, 3) the node's last increment Δu(n−½), kept before the solid steps

    @classmethod
    def zeros(cls, n_nodes: int) -> ContactArrays:
        return cls(
            np.zeros((n_nodes, 3)),
            np.zeros((n_nodes, 3)),
            np.zeros((n_nodes, 3)),
            np.zeros(n_nodes),
            np.zeros(n_nodes),
            np.zeros((n_nodes, 3)),
        )


@njit(cache=True)
def tooth_contact(qx, qy, qz, e1, e2, axis, teeth):
    """Penetration and outward normal of the deepest tooth at p − c = (qx, qy, qz); depth ≤ 0
    when every tooth is clear."""
    depth = nx = ny = nz = 0.0
    # the point in the spinning reamer frame
    lx = qx * e1[0] + qy * e1[1] + qz * e1[2]
    ly = qx * e2[0] + qy * e2[1] + qz * e2[2]
    lz = qx * axis[0] + qy * axis[1] + qz * axis[2]
    for k in range(len(teeth.tooth_cos)):
        across = -lx * teeth.tooth_sin[k] + ly * teeth.tooth_cos[k]
        if abs(across) >= teeth.edge_radius:
            continue
        along = lx * teeth.tooth_cos[k] + ly * teeth.tooth_sin[k]
        polar = min(max(pm.atan2(along, lz), teeth.tooth_start[k]), teeth.tooth_end[k])
        sin_polar, cos_polar = pm.sin(polar), pm.cos(polar)
        d_along = along - teeth.edge_axis_radius * sin_polar
        d_z = lz - teeth.edge_axis_radius * cos_polar
        # offset from the closest axis point: outward (radial), along the arc (beyond its ends)
        outward = d_along * sin_polar + d_z * cos_polar
        lengthwise = d_along * cos_polar - d_z * sin_polar
        if outward < 0.0:  # below the axis: the flat flanks, pushed sideways
            outward = 0.0
        distance = math.sqrt(outward * outward + lengthwise * lengthwise + across * across)
        tooth_depth = teeth.edge_radius - distance
        if tooth_depth > depth and distance > 0.0:
            depth = tooth_depth
            # normal in the tooth's meridian frame (e_ψ, e_⊥, D), then in the bone frame
            u_along = (outward * sin_polar + lengthwise * cos_polar) / distance
            u_z = (outward * cos_polar - lengthwise * sin_polar) / distance
            u_across = across / distance
            ux = u_along * teeth.tooth_cos[k] - u_across * teeth.tooth_sin[k]
            uy = u_along * teeth.tooth_sin[k] + u_across * teeth.tooth_cos[k]
            nx = ux * e1[0] + uy * e2[0] + u_z * axis[0]
            ny = ux * e1[1] + uy * e2[1] + u_z * axis[1]
            nz = ux * e1[2] + uy * e2[2] + u_z * axis[2]
    return depth, nx, ny, nz


@njit(cache=True, inline="always")
def _normal_force(depth, nx, ny, nz, rx, ry, rz, stiffness, damping):
    """Penalty + damper force along n (≥ 0: contact never pulls)."""
    return max(0.0, stiffness * depth - damping * (rx * nx + ry * ny + rz * nz))


@njit(parallel=True, cache=True)
def reamer_contact(nodes, solid, pose, teeth, law, out):
    """Write each node's contact force and energy terms into ``out``; return how many nodes touch.

    ``nodes`` are the reference positions, ``solid`` a :class:`~thrsim.physics.explicit.SolidArrays`
    (displacement, velocity, masses), ``pose`` a :class:`ReamerPose`, ``teeth`` a
    :class:`ReamerTeeth`, ``law`` a :class:`ContactLaw`, ``out`` a :class:`ContactArrays`.
    """
    centre, e1, e2, axis = pose.centre, pose.e1, pose.e2, pose.axis
    omega, axial_speed = pose.omega, pose.axial_speed
    stiffness_per_mass = law.penalty_factor / (law.dt * law.dt)
    # arrays taken out of the tuples before the parallel loop, one per statement: Numba 0.68's
    # parfor pass loses writes made through a tuple attribute inside prange, and writes to an
    # array bound by a multiple assignment (a, b = t.a, t.b)
    force = out.force
    surface_velocity = out.surface_velocity
    normal_force = out.normal_force
    penalty_energy = out.penalty_energy
    cutting_damage = out.cutting_damage
    offsets = solid.offsets
    entries = solid.entries
    active = solid.active
    material = solid.material
    volume = solid.volume
    displacement = solid.displacement
    velocity = solid.velocity
    nodal_mass = solid.nodal_mass
    inverse_mass = solid.inverse_mass
    contact_nodes = solid.contact_nodes
    contacts = 0
    for index in prange(len(contact_nodes)):
        node = contact_nodes[index]
        fx = fy = fz = wx = wy = wz = bx = by = bz = stored = cut = 0.0
        touching = 0
        if inverse_mass[node] > 0.0:  # orphaned nodes (every element gone) are skipped
            qx = nodes[node, 0] + displacement[node, 0] - centre[0]
            qy = nodes[node, 1] + displacement[node, 1] - centre[1]
            qz = nodes[node, 2] + displacement[node, 2] - centre[2]
            r = math.sqrt(qx * qx + qy * qy + qz * qz)
            if 0.0 < r < teeth.edge_axis_radius + teeth.edge_radius:
                head_depth = teeth.head_radius - r
                tooth_depth, tx, ty, tz = 0.0, 0.0, 0.0, 0.0
                if r > teeth.edge_axis_radius - teeth.edge_radius:  # in the teeth's shell
                    tooth_depth, tx, ty, tz = tooth_contact(qx, qy, qz, e1, e2, axis, teeth)
                if head_depth > 0.0 or tooth_depth > 0.0:
                    mass = nodal_mass[node]
                    stiffness = stiffness_per_mass * mass
                    damping = 2.0 * law.damping_ratio * math.sqrt(stiffness * mass)
                    # reamer surface velocity at the node: ω D × (p − c) + ṡ D
                    wx = omega * (axis[1] * qz - axis[2] * qy) + axial_speed * axis[0]
                    wy = omega * (axis[2] * qx - axis[0] * qz) + axial_speed * axis[1]
                    wz = omega * (axis[0] * qy - axis[1] * qx) + axial_speed * axis[2]
                    rx = velocity[node, 0] - wx
                    ry = velocity[node, 1] - wy
                    rz = velocity[node, 2] - wz
                    head_fn = tooth_fn = 0.0
                    if head_depth > 0.0:
                        hx, hy, hz = qx / r, qy / r, qz / r
                        head_fn = _normal_force(head_depth, hx, hy, hz, rx, ry, rz, stiffness, damping)
                        bx += head_fn * hx
                        by += head_fn * hy
                        bz += head_fn * hz
                        if head_fn > 0.0:
                            stored += 0.5 * stiffness * head_depth * head_depth
                    if tooth_depth > 0.0:
                        tooth_fn = _normal_force(tooth_depth, tx, ty, tz, rx, ry, rz, stiffness, damping)
                        bx += tooth_fn * tx
                        by += tooth_fn * ty
                        bz += tooth_fn * tz
                        if tooth_fn > 0.0:
                            stored += 0.5 * stiffness * tooth_depth * tooth_depth
                    fn = math.sqrt(bx * bx + by * by + bz * bz)
                    if fn > 0.0:
                        nx, ny, nz = bx / fn, by / fn, bz / fn
                        normal_speed = rx * nx + ry * ny + rz * nz
                        sx = rx - normal_speed * nx
                        sy = ry - normal_speed * ny
                        sz = rz - normal_speed * nz
                        slip = math.sqrt(sx * sx + sy * sy + sz * sz)
                        # force per unit slip speed: Coulomb, capped at a fraction of the one-step stick force
                        ft = min(law.friction * fn / slip, STICK_FRACTION * mass / law.dt) if slip > 0.0 else 0.0
                        fx = bx - ft * sx
                        fy = by - ft * sy
                        fz = bz - ft * sz
                        touching = 1
                        if tooth_fn > 0.0 and slip > 0.0:
                            # the tooth's share of the friction work cuts (module docstring)
                            attached = energy = 0.0
                            first, mixed = -1, False
                            for entry in range(offsets[node], offsets[node + 1]):
                                e = entries[entry] // 4
                                if active[e] != 0:
                                    attached += volume[e]
                                    energy += volume[e] * law.cutting_energy[material[e]]
                                    if first < 0:
                                        first = material[e]
                                    elif material[e] != first:
                                        mixed = True
                            if attached > 0.0:
                                # Coulomb's μ·f_n, not the stability-capped force: the cap scales with the
                                # (scaled) nodal mass and so with Δt, and would make the cut depend on the step
                                work = law.friction * fn * slip * law.dt * tooth_fn / (tooth_fn + head_fn)
                                cut = work / (energy if mixed else law.cutting_energy[first] * attached)
        if touching == 0:
            wx = wy = wz = bx = by = bz = stored = 0.0
        force[node, 0] = fx
        force[node, 1] = fy
        force[node, 2] = fz
        surface_velocity[node, 0] = wx
        surface_velocity[node, 1] = wy
        surface_velocity[node, 2] = wz
        normal_force[node, 0] = bx
        normal_force[node, 1] = by
        normal_force[node, 2] = bz
        penalty_energy[node] = stored
        cutting_damage[node] = cut
        contacts += touching
    return contacts


@njit(cache=True)
def contact_totals(out, nodes, totals):
    """Force on the bone (3) and the penalty energy, summed over ``nodes`` (the contact candidates) in
    order into ``totals``."""
    for i in range(4):
        totals[i] = 0.0
    for index in range(len(nodes)):
        node = nodes[index]
        totals[0] += out.force[node, 0]
        totals[1] += out.force[node, 1]
        totals[2] += out.force[node, 2]
        totals[3] += out.penalty_energy[node]


@njit(cache=True)
def keep_previous_increment(out, nodes, du):
    """Keep each touched node's last increment Δu(n−½) before the solid steps (see
    :func:`contact_step_work`)."""
    for index in range(len(nodes)):
        node = nodes[index]
        if out.force[node, 0] != 0.0 or out.force[node, 1] != 0.0 or out.force[node, 2] != 0.0:
            for i in range(3):
                out.previous_du[node, i] = du[node, i]


@njit(cache=True)
def contact_step_work(out, nodes, du, axis, axial_speed, advance, dt, work):
    """Work of the step's contact forces, each through the displacement it acted over.

    The reamer surface at a node moved by (ω D × (p − c))·Δt + D·Δs (spin, then the reamer's
    actual axial step Δs), the node by ½(Δu(n−½) + Δu(n+½)): the force of step n works through the
    mean of the increments before and after it, the trapezoidal rule with which the bone's
    kinetic energy at half steps closes (Belytschko, Liu & Moran, Nonlinear Finite Elements for
    Continua and Structures, 2000, §6.2.3; Δu(n+½) alone over-books f·Δt²·a/2 a step wherever
    the touched nodes accelerate). Adds to ``work``: [0] the motor's spin work Σ f·(ω D × (p −
    c))·Δt, [1] the work on the bone, [2] friction, the tangential force through the relative
    slip, [3] the normal forces through the relative approach (penalty energy stored plus
    contact damping dissipated). Summed in node order.
    """
    for index in range(len(nodes)):
        node = nodes[index]
        fx, fy, fz = out.force[node, 0], out.force[node, 1], out.force[node, 2]
        if fx == 0.0 and fy == 0.0 and fz == 0.0:
            continue
        ux = 0.5 * (out.previous_du[node, 0] + du[node, 0])
        uy = 0.5 * (out.previous_du[node, 1] + du[node, 1])
        uz = 0.5 * (out.previous_du[node, 2] + du[node, 2])
        sx = (out.surface_velocity[node, 0] - axial_speed * axis[0]) * dt
        sy = (out.surface_velocity[node, 1] - axial_speed * axis[1]) * dt
        sz = (out.surface_velocity[node, 2] - axial_speed * axis[2]) * dt
        work[0] += fx * sx + fy * sy + fz * sz
        work[1] += fx * ux + fy * uy + fz * uz
        rx = sx + advance * axis[0] - ux
        ry = sy + advance * axis[1] - uy
        rz = sz + advance * axis[2] - uz
        normal_work = out.normal_force[node, 0] * rx + out.normal_force[node, 1] * ry + out.normal_force[node, 2] * rz
        work[3] += normal_work
        work[2] += fx * rx + fy * ry + fz * rz - normal_work
