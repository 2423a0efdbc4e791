"""Explicit central-difference dynamics of a damaging Johnson–Cook solid on linear tets.

Written here: no Python library combines explicit dynamics, rate-dependent JC plasticity,
ductile damage and element deletion (the docs' Physics page, Solver). Two Numba kernels a step:
:func:`element_update`, parallel over elements (strain increment, JC or crushable-foam return, damage plus
the teeth's cutting damage, deletion at D ≥ 1, bulk viscosity, nodal forces), and
:func:`node_update`, parallel over nodes (element forces gathered through a node→element CSR,
race-free, then central differences). :class:`ExplicitSolid` owns the state; contact and loads
are the caller's. Stress is stored undamaged (σ̄, Voigt order xx, yy, zz, xy, yz, zx; Cauchy is
(1 − D)·σ̄). Only the zone the caller sets (:meth:`ExplicitSolid.set_zone`, default the whole
mesh) is integrated; each element has one material (a :class:`Tissue`), by the mesh's tags.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numba import njit, prange
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from thrsim.config import BoneMaterial, CrushableFoam, JohnsonCookDamage, JohnsonCookHardening
from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.tet_metrics import minimum_altitudes
from thrsim.physics.material import (
    characteristic_length,
    crushed_flow_stress,
    damage_initiation_increment,
    foam_return,
    jc_radial_return,
    jc_yield_stress,
)
from thrsim.physics.tet_kinematics import MassScaling, lumped_nodal_mass, mass_scaling, node_element_csr, shape_gradients

#: ABAQUS/Explicit's default linear bulk viscosity coefficient: damps ringing at contact impacts
LINEAR_BULK_VISCOSITY = 0.06


class SolidArrays(NamedTuple):
    """Every array the step kernels read or write, by name (Numba takes it as one typed tuple).

    Static: mesh, gradients, volumes, lengths, masses, node→element CSR, supports. State: the
    rest, updated in place. Add a field here and in :meth:`ExplicitSolid.arrays`, nowhere else.
    """

    tets: np.ndarray  # (E, 4) int64
    zone_elements: np.ndarray  # (K,) int64 elements integrated this step (the zone)
    zone_nodes: np.ndarray  # (M,) int64 nodes integrated: those whose every element is in the zone
    contact_nodes: np.ndarray  # (L,) int64 nodes the reamer may touch: every node of a zone element
    material: np.ndarray  # (E,) int64 row of the element's material in MaterialConstants
    grads: np.ndarray  # (E, 4, 3) ∂N/∂x
    volume: np.ndarray  # (E,)
    char_length: np.ndarray  # (E,) damage length L_e
    bulk_viscosity: np.ndarray  # (E,) b1·ρ·c_d·h coefficient
    offsets: np.ndarray  # (N + 1,) node → element CSR
    entries: np.ndarray  # element·4 + local index
    support_stiffness: np.ndarray  # (N,) foundation springs
    held: np.ndarray  # (N,) bool, encastre
    active: np.ndarray  # (E,) uint8
    accounted: np.ndarray  # (E,) bool: deletion booked
    stress: np.ndarray  # (E, 6) effective σ̄, Voigt
    peeq: np.ndarray
    damage: np.ndarray
    initiation: np.ndarray
    plastic_work: np.ndarray  # (E,) J
    damage_work: np.ndarray  # (E,) J
    viscous_work: np.ndarray  # (E,) J, bulk viscosity
    viscous_pressure: np.ndarray  # (E,) Pa, the bulk-viscosity pressure applied in the last step
    static_flow_stress: np.ndarray  # (E,) Pa, flow stress at rate 0 at static_flow_peeq: an elastic step skips its powers
    static_flow_peeq: np.ndarray  # (E,) the εᵖ it was computed at (NaN: not yet); recomputed when εᵖ differs
    element_force: np.ndarray  # (E, 4, 3)
    nodal_mass: np.ndarray  # (N,)
    inverse_mass: np.ndarray  # (N,), 0 for orphaned nodes
    elements_at_node: np.ndarray  # (N,)
    velocity: np.ndarray  # (N, 3), v(n+½) after a step
    displacement: np.ndarray  # (N, 3)
    du: np.ndarray  # (N, 3) last step's increment
    external_force: np.ndarray  # (N, 3), e.g. contact
    cutting_damage: np.ndarray  # (N,) damage added this step to every active element at the node (tooth cutting)
    debris: np.ndarray  # (7,) what deleted elements took: mass, momentum (3), kinetic, count, elastic


class Tissue(NamedTuple):
    """One bone material: elastic constants, Johnson–Cook hardening and damage, and optionally
    compaction (a crushable foam's yield surface in place of von Mises', crushing never fracturing)."""

    material: BoneMaterial
    hardening: JohnsonCookHardening
    damage: JohnsonCookDamage
    compaction: CrushableFoam | None = None


class MaterialConstants(NamedTuple):
    """The step, and each material's scalars (SI) as arrays indexed by material row."""

    dt: float
    lam: np.ndarray
    mu: np.ndarray
    a: np.ndarray
    b: np.ndarray
    n: np.ndarray
    c: np.ndarray
    rate0: np.ndarray
    d1: np.ndarray
    d2: np.ndarray
    d3: np.ndarray
    d4: np.ndarray
    u_f: np.ndarray
    alpha: np.ndarray  # the crushable foam's α; 0 for a von Mises (JC) material
    eps_d: np.ndarray  # densification strain ε_D (inf without compaction)
    coef_d: np.ndarray  # densification D
    exp_d: np.ndarray  # densification m
    cap_d: np.ndarray  # the densified bone's flow stress, σ_c's ceiling (inf without compaction)

    @classmethod
    def of(cls, dt: float, tissues: Sequence[Tissue]) -> MaterialConstants:
        """The constants table of ``tissues`` (row k = tissue k) at step ``dt``."""

        def column(value) -> np.ndarray:
            return np.array([value(t) for t in tissues], dtype=np.float64)

        return cls(
            dt=float(dt),
            lam=column(lambda t: t.material.lame_lambda_pa),
            mu=column(lambda t: t.material.shear_modulus_pa),
            a=column(lambda t: t.hardening.a_pa),
            b=column(lambda t: t.hardening.b_pa),
            n=column(lambda t: t.hardening.n),
            c=column(lambda t: t.hardening.c),
            rate0=column(lambda t: t.hardening.reference_strain_rate_s),
            d1=column(lambda t: t.damage.d1),
            d2=column(lambda t: t.damage.d2),
            d3=column(lambda t: t.damage.d3),
            d4=column(lambda t: t.damage.d4),
            u_f=column(lambda t: t.damage.displacement_at_failure_m),
            alpha=column(lambda t: t.compaction.yield_ellipse_alpha if t.compaction else 0.0),
            eps_d=column(lambda t: t.compaction.densification_strain(t.material.density_kg_m3) if t.compaction else math.inf),
            coef_d=column(lambda t: t.compaction.densification_coefficient if t.compaction else 1.0),
            exp_d=column(lambda t: t.compaction.densification_exponent if t.compaction else 1.0),
            cap_d=column(lambda t: t.compaction.densified_flow_stress_pa if t.compaction else math.inf),
        )


@njit(parallel=True, cache=True)
def element_update(s, m):
    """Advance every active element's stress by one step and write its nodal forces.

    ``s`` is a :class:`SolidArrays`, ``m`` a :class:`MaterialConstants`. Returns the number of
    elements deleted during this step (their ``active`` flag is cleared and their forces zeroed).
    """
    deleted = 0
    dt = m.dt
    # the material table's columns, taken out of the tuple like the arrays below
    lam_of = m.lam
    mu_of = m.mu
    a_of = m.a
    b_of = m.b
    n_of = m.n
    c_of = m.c
    rate0_of = m.rate0
    d1_of = m.d1
    d2_of = m.d2
    d3_of = m.d3
    d4_of = m.d4
    u_f_of = m.u_f
    alpha_of = m.alpha
    eps_d_of = m.eps_d
    coef_d_of = m.coef_d
    exp_d_of = m.exp_d
    cap_d_of = m.cap_d
    zone_elements = s.zone_elements
    # arrays taken out of the tuple before the parallel loop, one per statement: Numba 0.68's
    # parfor pass loses writes made through a tuple attribute inside prange, and writes to an
    # array bound by a multiple assignment (a, b = t.a, t.b)
    tets = s.tets
    material = s.material
    grads = s.grads
    volume = s.volume
    char_length = s.char_length
    du = s.du
    bulk_viscosity = s.bulk_viscosity
    active = s.active
    stress = s.stress
    peeq = s.peeq
    damage = s.damage
    initiation = s.initiation
    plastic_work = s.plastic_work
    damage_work = s.damage_work
    viscous_work = s.viscous_work
    element_force = s.element_force
    viscous_pressure = s.viscous_pressure
    static_flow_stress = s.static_flow_stress
    static_flow_peeq = s.static_flow_peeq
    cutting_damage = s.cutting_damage
    for index in prange(len(zone_elements)):
        e = zone_elements[index]
        if active[e] == 0:
            continue
        row = material[e]
        lam = lam_of[row]
        mu = mu_of[row]
        poisson = lam / (2.0 * (lam + mu))
        youngs = mu * (3.0 * lam + 2.0 * mu) / (lam + mu)
        # strain increment dε = sym(Σ_a du_a ⊗ ∇N_a)
        h00 = h01 = h02 = h10 = h11 = h12 = h20 = h21 = h22 = 0.0
        for k in range(4):
            node = tets[e, k]
            ux, uy, uz = du[node, 0], du[node, 1], du[node, 2]
            gx, gy, gz = grads[e, k, 0], grads[e, k, 1], grads[e, k, 2]
            h00 += ux * gx
            h01 += ux * gy
            h02 += ux * gz
            h10 += uy * gx
            h11 += uy * gy
            h12 += uy * gz
            h20 += uz * gx
            h21 += uz * gy
            h22 += uz * gz
        exx, eyy, ezz = h00, h11, h22
        exy = 0.5 * (h01 + h10)
        eyz = 0.5 * (h12 + h21)
        ezx = 0.5 * (h20 + h02)
        trace = exx + eyy + ezz
        sxx = stress[e, 0] + lam * trace + 2.0 * mu * exx
        syy = stress[e, 1] + lam * trace + 2.0 * mu * eyy
        szz = stress[e, 2] + lam * trace + 2.0 * mu * ezz
        sxy = stress[e, 3] + 2.0 * mu * exy
        syz = stress[e, 4] + 2.0 * mu * eyz
        szx = stress[e, 5] + 2.0 * mu * ezx
        pressure = (sxx + syy + szz) / 3.0
        dxx, dyy, dzz = sxx - pressure, syy - pressure, szz - pressure
        q_trial = math.sqrt(1.5 * (dxx * dxx + dyy * dyy + dzz * dzz + 2.0 * (sxy * sxy + syz * syz + szx * szx)))
        alpha = alpha_of[row]
        dpeeq = 0.0
        flow_stress = 0.0
        deviator_scale = 1.0
        triaxiality = 0.0
        fracturing = True  # whether this step's plastic strain counts toward ductile damage
        if alpha > 0.0:
            # crushable foam: both the deviator and the mean stress return; crushing (triaxiality at
            # or below −1/3, Bao and Wierzbicki's cutoff) compacts the bone and never fractures it.
            # σ_c is never under A: inside √(1 + α²/9)·A the step is elastic, with no call into the return
            gamma = 0.0
            if q_trial * q_trial + alpha * alpha * pressure * pressure > (1.0 + alpha * alpha / 9.0) * a_of[row] * a_of[row]:
                if static_flow_peeq[e] != peeq[e]:
                    static_flow_stress[e] = crushed_flow_stress(
                        peeq[e], 0.0, a_of[row], b_of[row], n_of[row], c_of[row], rate0_of[row], eps_d_of[row], coef_d_of[row],
                        exp_d_of[row], cap_d_of[row],
                    )  # fmt: skip
                    static_flow_peeq[e] = peeq[e]
                gamma, dpeeq = foam_return(
                    q_trial, pressure, peeq[e], static_flow_stress[e], dt, mu, lam + 2.0 * mu / 3.0, alpha, a_of[row], b_of[row],
                    n_of[row], c_of[row], rate0_of[row], eps_d_of[row], coef_d_of[row], exp_d_of[row], cap_d_of[row],
                )  # fmt: skip
            if dpeeq > 0.0:
                deviator_scale = 1.0 / (1.0 + 6.0 * mu * gamma)
                pressure /= 1.0 + 2.0 * (lam + 2.0 * mu / 3.0) * alpha * alpha * gamma
                q_new = deviator_scale * q_trial
                flow_stress = math.sqrt((q_new * q_new + alpha * alpha * pressure * pressure) / (1.0 + alpha * alpha / 9.0))
                # fully dense (at the tissue's strength) it fractures as solid bone, whatever the triaxiality
                fracturing = 3.0 * pressure > -q_new * (1.0 - 1e-9) or flow_stress >= cap_d_of[row] * (1.0 - 1e-9)
                # hydrostatic tension (q = 0) reads as a large positive triaxiality
                triaxiality = pressure / max(q_new, 1e-9 * flow_stress)
        else:
            # the flow stress is never under A: at or below it the step is elastic, with no call into the
            # return mapping (whose own first test, against A + B·εᵖⁿ, would say the same at a power's cost)
            if q_trial > a_of[row]:
                if static_flow_peeq[e] != peeq[e]:
                    static_flow_stress[e] = jc_yield_stress(peeq[e], 0.0, a_of[row], b_of[row], n_of[row], c_of[row], rate0_of[row])
                    static_flow_peeq[e] = peeq[e]
                dpeeq = jc_radial_return(
                    q_trial, peeq[e], static_flow_stress[e], dt, mu, a_of[row], b_of[row], n_of[row], c_of[row], rate0_of[row]
                )
            if dpeeq > 0.0:
                deviator_scale = 1.0 - 3.0 * mu * dpeeq / q_trial
                q_new = deviator_scale * q_trial
                flow_stress = q_new
                triaxiality = pressure / q_new
        if dpeeq > 0.0:
            # both returns scale the deviator; only the foam's also moves the mean stress
            dxx *= deviator_scale
            dyy *= deviator_scale
            dzz *= deviator_scale
            sxy *= deviator_scale
            syz *= deviator_scale
            szx *= deviator_scale
            sxx, syy, szz = dxx + pressure, dyy + pressure, dzz + pressure
            peeq[e] += dpeeq
            plastic_work[e] += (1.0 - damage[e]) * flow_stress * dpeeq * volume[e]
            if fracturing and initiation[e] < 1.0:
                initiation[e] += damage_initiation_increment(
                    dpeeq, triaxiality, dpeeq / dt, d1_of[row], d2_of[row], d3_of[row], d4_of[row], rate0_of[row]
                )
            elif fracturing:
                grown = min(1.0, damage[e] + char_length[e] * dpeeq / u_f_of[row]) - damage[e]
                damage[e] += grown
                # strain energy released as the stiffness degrades: ΔD·½σ̄:C⁻¹:σ̄·V
                damage_work[e] += grown * strain_energy_density(sxx, syy, szz, sxy, syz, szx, youngs, poisson) * volume[e]
        cut = 0.0
        for k in range(4):
            cut += cutting_damage[tets[e, k]]
        if cut > 0.0:
            grown = min(1.0, damage[e] + cut) - damage[e]
            damage[e] += grown
            damage_work[e] += grown * strain_energy_density(sxx, syy, szz, sxy, syz, szx, youngs, poisson) * volume[e]
        stress[e, 0] = sxx
        stress[e, 1] = syy
        stress[e, 2] = szz
        stress[e, 3] = sxy
        stress[e, 4] = syz
        stress[e, 5] = szx
        v = volume[e]
        # the pressure applied last step worked through the strain increment it produced (deleted or not)
        viscous_work[e] += viscous_pressure[e] * trace * v
        if damage[e] >= 1.0:
            active[e] = 0
            deleted += 1
            for k in range(4):
                for i in range(3):
                    element_force[e, k, i] = 0.0
            continue
        keep = 1.0 - damage[e]
        viscous = bulk_viscosity[e] * trace / dt
        viscous_pressure[e] = viscous
        txx = keep * sxx + viscous
        tyy = keep * syy + viscous
        tzz = keep * szz + viscous
        txy, tyz, tzx = keep * sxy, keep * syz, keep * szx
        for k in range(4):
            gx, gy, gz = grads[e, k, 0], grads[e, k, 1], grads[e, k, 2]
            element_force[e, k, 0] = -v * (txx * gx + txy * gy + tzx * gz)
            element_force[e, k, 1] = -v * (txy * gx + tyy * gy + tyz * gz)
            element_force[e, k, 2] = -v * (tzx * gx + tyz * gy + tzz * gz)
    return deleted


@njit(cache=True, inline="always")
def strain_energy_density(sxx, syy, szz, sxy, syz, szx, youngs, poisson):
    """½ σ:C⁻¹:σ of an isotropic elastic stress (J/m³)."""
    contracted = sxx * sxx + syy * syy + szz * szz + 2.0 * (sxy * sxy + syz * syz + szx * szx)
    trace = sxx + syy + szz
    return ((1.0 + poisson) * contracted - poisson * trace * trace) / (2.0 * youngs)


@njit(parallel=True, cache=True)
def node_update(s, dt):
    """Central difference: v(n+½) = v(n−½) + Δt·M⁻¹(f_ext − f_int − k·u), u(n+1) = u(n) + Δt·v(n+½).

    ``held`` nodes (the encastre) and orphaned nodes (inverse mass 0) do not move;
    ``support_stiffness`` ties nodes elastically to their rest positions (0: no spring).
    """
    held = s.held
    inverse_mass = s.inverse_mass
    velocity = s.velocity
    displacement = s.displacement
    du = s.du
    support_stiffness = s.support_stiffness
    external_force = s.external_force
    offsets = s.offsets
    entries = s.entries
    element_force = s.element_force
    zone_nodes = s.zone_nodes
    for index in prange(len(zone_nodes)):
        node = zone_nodes[index]
        if held[node] or inverse_mass[node] == 0.0:
            for i in range(3):
                velocity[node, i] = 0.0
                du[node, i] = 0.0
            continue
        spring = support_stiffness[node]
        fx = external_force[node, 0] - spring * displacement[node, 0]
        fy = external_force[node, 1] - spring * displacement[node, 1]
        fz = external_force[node, 2] - spring * displacement[node, 2]
        for entry in range(offsets[node], offsets[node + 1]):
            e, k = entries[entry] // 4, entries[entry] % 4
            fx += element_force[e, k, 0]
            fy += element_force[e, k, 1]
            fz += element_force[e, k, 2]
        w = dt * inverse_mass[node]
        velocity[node, 0] += w * fx
        velocity[node, 1] += w * fy
        velocity[node, 2] += w * fz
        for i in range(3):
            du[node, i] = dt * velocity[node, i]
            displacement[node, i] += du[node, i]


@njit(cache=True)
def account_deletions(s, elements):
    """Book newly deleted ``elements``; a node left with no active element leaves the model.

    A node keeps its whole lumped mass while any of its elements is active, and takes it with its
    last one. With the masses fixed, deleting elements only takes stiffness away, so the mesh's
    highest frequency can only fall and a step stable for the intact mesh stays stable (a node
    left with one element's mass would ring at that lone element's frequency, which can pass 2/Δt;
    docs' Physics page, Materials). ``debris`` accumulates
    what left: [mass, px, py, pz, kinetic energy, count, elastic energy], so momentum and energy
    balance across deletion (the elastic part is booked by the caller that deletes elements still
    carrying stress).
    """
    for index in range(len(elements)):
        e = elements[index]
        if s.active[e] != 0 or s.accounted[e]:
            continue
        s.accounted[e] = True
        s.debris[5] += 1.0
        for k in range(4):
            node = s.tets[e, k]
            s.elements_at_node[node] -= 1
            if s.elements_at_node[node] > 0:
                continue
            mass = s.nodal_mass[node]
            vx, vy, vz = s.velocity[node, 0], s.velocity[node, 1], s.velocity[node, 2]
            s.debris[0] += mass
            s.debris[1] += mass * vx
            s.debris[2] += mass * vy
            s.debris[3] += mass * vz
            s.debris[4] += 0.5 * mass * (vx * vx + vy * vy + vz * vz)
            s.nodal_mass[node] = 0.0
            s.inverse_mass[node] = 0.0
            s.velocity[node, 0] = 0.0
            s.velocity[node, 1] = 0.0
            s.velocity[node, 2] = 0.0


@njit(cache=True)
def solid_step(s, m):
    """One central-difference step of the solid: stresses, deletions, then nodes. Returns deletions."""
    deleted = element_update(s, m)
    if deleted > 0:
        account_deletions(s, s.zone_elements)
    node_update(s, m.dt)
    return deleted


def von_mises(stress: np.ndarray) -> np.ndarray:
    """Von Mises equivalent of Voigt stresses (…, 6)."""
    s = np.asarray(stress)
    p = s[..., :3].mean(axis=-1, keepdims=True)
    dev = s[..., :3] - p
    return np.sqrt(1.5 * ((dev**2).sum(axis=-1) + 2.0 * (s[..., 3:] ** 2).sum(axis=-1)))


class ExplicitSolid:
    """A damaging JC solid on a tet mesh, advanced by central differences at a fixed step.

    ``material``, ``hardening`` and ``damage`` are the cortical bone's (every element of a mesh
    without material tags); ``other_tissues`` maps the mesh's other material names (``cancellous``)
    to theirs. ``target_dt_s`` sets the step reached by per-element mass scaling (None: the unscaled
    Courant step); ``mass_scaling_dt_s``, when given, scales the mass for that step instead (at
    least ``target_dt_s``), so a convergence study can shorten the step with the mass held.
    ``held`` nodes default to the mesh's fixed nodes.
    """

    def __init__(
        self,
        mesh: TetMesh,
        material: BoneMaterial,
        hardening: JohnsonCookHardening,
        damage: JohnsonCookDamage,
        target_dt_s: float | None,
        safety: float = 0.9,
        held_nodes: np.ndarray | None = None,
        bulk_viscosity: float = LINEAR_BULK_VISCOSITY,
        support_stiffness: np.ndarray | None = None,
        other_tissues: dict[str, Tissue] | None = None,
        mass_scaling_dt_s: float | None = None,
    ) -> None:
        self.mesh = mesh
        self.material, self.hardening, self.damage_law = material, hardening, damage
        self.tissues = tissues_of(mesh, Tissue(material, hardening, damage), other_tissues or {})
        nodes, tets = mesh.nodes, mesh.tets
        self.tets = tets.astype(np.int64)
        self.element_material = mesh.element_material.astype(np.int64)
        self.grads = shape_gradients(nodes, self.tets)
        self.volume = np.abs(mesh.volumes)
        self.char_length = characteristic_length(self.volume)
        constants_of = MaterialConstants.of(0.0, self.tissues)
        self.lam, self.mu = constants_of.lam[self.element_material], constants_of.mu[self.element_material]
        p_wave = self.lam + 2.0 * self.mu
        density = np.array([t.material.density_kg_m3 for t in self.tissues])[self.element_material]
        self.youngs_modulus = np.array([t.material.youngs_modulus_pa for t in self.tissues])[self.element_material]
        self.poisson_ratio = np.array([t.material.poisson_ratio for t in self.tissues])[self.element_material]
        scaled_for = target_dt_s if mass_scaling_dt_s is None else mass_scaling_dt_s
        self.scaling: MassScaling = mass_scaling(nodes, self.tets, density, p_wave, scaled_for, safety)
        self.dt = float(target_dt_s) if target_dt_s is not None else self.scaling.stable_dt_s
        if self.dt > self.scaling.stable_dt_s * (1 + 1e-9):
            raise ValueError(f"time step {self.dt:.3g} s exceeds the stable step {self.scaling.stable_dt_s:.3g} s")
        rho = self.scaling.element_density
        self.element_mass = rho * self.volume
        # ABAQUS linear bulk viscosity b1·ρ·c_d·L with the density actually used and L the
        # Courant length (smallest altitude): with the longer damage length L_e the damping of
        # the highest mode grows past what the 0.9 safety factor absorbs and the step diverges
        self.bulk_viscosity_coefficient = bulk_viscosity * np.sqrt(rho * p_wave) * minimum_altitudes(nodes, self.tets)
        n_nodes = mesh.n_nodes
        self.nodal_mass = lumped_nodal_mass(n_nodes, self.tets, self.element_mass)
        self.inverse_mass = np.where(self.nodal_mass > 0, 1.0 / np.maximum(self.nodal_mass, 1e-300), 0.0)
        self.elements_at_node = np.bincount(self.tets.ravel(), minlength=n_nodes)
        self.offsets, self.entries = node_element_csr(n_nodes, self.tets)
        self.support_stiffness = np.zeros(n_nodes) if support_stiffness is None else np.asarray(support_stiffness, dtype=float)
        self.held = np.zeros(n_nodes, dtype=np.bool_)
        self.held[mesh.fixed_nodes if held_nodes is None else np.asarray(held_nodes, dtype=np.int64)] = True

        n_el = mesh.n_tets
        self.time = 0.0
        self.displacement = np.zeros((n_nodes, 3))
        self.velocity = np.zeros((n_nodes, 3))
        self.du = np.zeros((n_nodes, 3))
        self.stress = np.zeros((n_el, 6))
        self.peeq = np.zeros(n_el)
        self.damage = np.zeros(n_el)
        self.initiation = np.zeros(n_el)
        self.plastic_work = np.zeros(n_el)
        self.damage_work = np.zeros(n_el)
        self.active = np.ones(n_el, dtype=np.uint8)
        self.viscous_work = np.zeros(n_el)
        self.viscous_pressure = np.zeros(n_el)
        self.static_flow_stress = np.zeros(n_el)
        self.static_flow_peeq = np.full(n_el, np.nan)
        self.element_force = np.zeros((n_el, 4, 3))
        self.external_force = np.zeros((n_nodes, 3))
        self.cutting_damage = np.zeros(n_nodes)
        # what deleted elements took with them: [mass, momentum (3), kinetic energy, count, elastic energy]
        self.debris = np.zeros(7)
        self.detached_count = 0
        self._accounted = np.zeros(n_el, dtype=np.bool_)
        self.constants = MaterialConstants.of(self.dt, self.tissues)
        self.all_elements = np.arange(n_el, dtype=np.int64)
        self.all_nodes = np.arange(n_nodes, dtype=np.int64)
        self.integrated = np.ones(n_nodes, dtype=bool)  # nodes the zone integrates
        self.arrays = SolidArrays(
            tets=self.tets, zone_elements=self.all_elements, zone_nodes=self.all_nodes, contact_nodes=self.all_nodes, material=self.element_material, grads=self.grads, volume=self.volume, char_length=self.char_length,
            bulk_viscosity=self.bulk_viscosity_coefficient,
            offsets=self.offsets, entries=self.entries, support_stiffness=self.support_stiffness, held=self.held,
            active=self.active, accounted=self._accounted, stress=self.stress, peeq=self.peeq, damage=self.damage,
            initiation=self.initiation, plastic_work=self.plastic_work, damage_work=self.damage_work,
            viscous_work=self.viscous_work, viscous_pressure=self.viscous_pressure,
            static_flow_stress=self.static_flow_stress, static_flow_peeq=self.static_flow_peeq, element_force=self.element_force, nodal_mass=self.nodal_mass,
            inverse_mass=self.inverse_mass, elements_at_node=self.elements_at_node, velocity=self.velocity,
            displacement=self.displacement, du=self.du, external_force=self.external_force,
            cutting_damage=self.cutting_damage, debris=self.debris,
        )  # fmt: skip

    def set_zone(self, in_zone: np.ndarray | None) -> np.ndarray:
        """Integrate only the elements flagged in ``in_zone`` (None: every element) until the next call.

        The zone's nodes that also belong to an active element outside it are held where they are
        (the zone's support); a node that stops being integrated keeps its velocity but no longer
        moves. Returns the nodes of zone elements, those the reamer may touch (a bool mask)."""
        n_nodes = len(self.inverse_mass)
        if in_zone is None:
            elements, touched = self.all_elements, np.ones(n_nodes, dtype=bool)
            integrated = touched
        else:
            elements = np.flatnonzero(in_zone).astype(np.int64)
            touched = np.zeros(n_nodes, dtype=bool)
            touched[self.tets[elements].ravel()] = True
            supports = np.zeros(n_nodes, dtype=bool)
            supports[self.tets[~in_zone & (self.active > 0)].ravel()] = True
            integrated = touched & ~supports
        self.du[self.integrated & ~integrated] = 0.0
        self.integrated = integrated
        self.arrays = self.arrays._replace(
            zone_elements=elements,
            zone_nodes=np.flatnonzero(integrated).astype(np.int64),
            contact_nodes=np.flatnonzero(touched).astype(np.int64),
        )
        return touched

    @property
    def alive_nodes(self) -> np.ndarray:
        """Nodes still attached to at least one active element."""
        return self.inverse_mass > 0.0

    def step(self) -> int:
        """One central-difference step under ``external_force`` (set it in place); returns deletions."""
        deleted = solid_step(self.arrays, self.constants)
        self.time += self.dt
        return deleted

    @property
    def deleted_mass(self) -> float:
        return float(self.debris[0])

    @property
    def deleted_momentum(self) -> np.ndarray:
        return self.debris[1:4].copy()

    @property
    def deleted_kinetic_energy(self) -> float:
        return float(self.debris[4])

    @property
    def deleted_count(self) -> int:
        return int(self.debris[5])

    @property
    def deleted_elastic_energy(self) -> float:
        """Strain energy of detached chips, deleted while still stressed."""
        return float(self.debris[6])

    def viscous_dissipation(self) -> float:
        return float(self.viscous_work.sum())

    def remove_elements(self, removed: np.ndarray) -> int:
        """Take these elements out before the run (bone reamed away earlier): their mass leaves the
        nodes, as at deletion, with nothing booked as debris. Returns how many were active."""
        removed = np.asarray(removed, dtype=bool) & (self.active > 0)
        self.active[removed] = 0
        self.damage[removed] = 1.0
        account_deletions(self.arrays, self.all_elements)
        self._accounted[removed] = True
        self.debris[:] = 0.0
        return int(removed.sum())

    def delete_detached(self) -> int:
        """Delete active elements no longer face-connected, through active elements, to supported bone.

        Such chips are debris: the thesis excludes removed material from the calculation [5.2.1],
        and a free chip batted about by the teeth would only add noise. Returns how many went.
        """
        pairs = self.mesh.adjacency.pairs
        both = (self.active[pairs[:, 0]] > 0) & (self.active[pairs[:, 1]] > 0)
        live = pairs[both]
        n = len(self.active)
        graph = coo_matrix((np.ones(len(live)), (live[:, 0], live[:, 1])), shape=(n, n))
        _, label = connected_components(graph, directed=False)
        supported = self.held | (self.support_stiffness > 0)
        anchored_elements = (self.active > 0) & supported[self.tets].any(axis=1)
        anchored = np.zeros(label.max() + 1, dtype=bool)
        anchored[label[anchored_elements]] = True
        detached = (self.active > 0) & ~anchored[label]
        count = int(detached.sum())
        if count:
            self.debris[6] += float(self.element_elastic_energy()[detached].sum())
            self.active[detached] = 0
            self.damage[detached] = 1.0
            self.detached_count += count
            account_deletions(self.arrays, self.all_elements)
        return count

    def von_mises(self) -> np.ndarray:
        """Von Mises stress of the (damaged) Cauchy stress, 0 for deleted elements, Pa."""
        return np.where(self.active > 0, (1.0 - self.damage) * von_mises(self.stress), 0.0)

    def kinetic_energy(self) -> float:
        return float(0.5 * (self.nodal_mass * (self.velocity**2).sum(axis=1)).sum())

    def momentum(self) -> np.ndarray:
        return (self.nodal_mass[:, None] * self.velocity).sum(axis=0)

    def element_elastic_energy(self) -> np.ndarray:
        """(1 − D)·½ σ̄:C⁻¹:σ̄·V of each element (J), 0 for deleted ones."""
        e, nu = self.youngs_modulus, self.poisson_ratio
        st = self.stress
        contracted = (st[:, :3] ** 2).sum(axis=1) + 2.0 * (st[:, 3:] ** 2).sum(axis=1)
        density = ((1 + nu) * contracted - nu * st[:, :3].sum(axis=1) ** 2) / (2.0 * e)
        return np.where(self.active > 0, 1.0 - self.damage, 0.0) * density * self.volume

    def elastic_energy(self) -> float:
        """Σ (1 − D)·½ σ̄:C⁻¹:σ̄·V over active elements, plus the support springs' ½ k u²."""
        springs = 0.5 * (self.support_stiffness * (self.displacement**2).sum(axis=1))[self.alive_nodes].sum()
        return float(self.element_elastic_energy().sum() + springs)

    def plastic_dissipation(self) -> float:
        return float(self.plastic_work.sum())

    def damage_dissipation(self) -> float:
        """Strain energy released by stiffness degradation (ABAQUS's ALLDMD)."""
        return float(self.damage_work.sum())


def tissues_of(mesh: TetMesh, cortical: Tissue, others: dict[str, Tissue]) -> list[Tissue]:
    """The tissue of each of the mesh's material names, in its tag order; an unknown name is refused."""
    known = {"cortical": cortical, **others}
    missing = [name for name in mesh.material_names if name not in known]
    if missing:
        raise ThrsimInputError(f"the mesh names material(s) {', '.join(missing)} that have no constants (known: {', '.join(known)})")
    return [known[name] for name in mesh.material_names]
