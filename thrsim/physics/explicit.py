"""Explicit central-difference dynamics of a damaging Johnson–Cook solid on linear tets.

Written here because no Python library combines explicit dynamics, JC plasticity with rate
dependence, ductile damage and element deletion (see NOTES: torch-fem, warp.fem, scikit-fem,
SfePy were checked). Kernels are Numba; the two per-step kernels are:

* :func:`element_update`, parallel over elements: strain increment from the reference
  gradients, elastic trial stress, JC radial return, damage initiation/evolution, deletion at
  D ≥ 1, linear bulk viscosity (ABAQUS's b1 = 0.06) and the element's nodal forces;
* :func:`node_update`, parallel over nodes: gathers element forces through a node→element CSR
  (race-free, no atomics), adds external forces, integrates v and u (central difference),
  holds fixed nodes.

State is owned by :class:`ExplicitSolid`; contact and loads are the caller's (the reaming case
adds the reamer's contact forces as external forces every step). Stress is stored undamaged
(effective, σ̄) in Voigt order xx, yy, zz, xy, yz, zx; the Cauchy stress is (1 − D)·σ̄.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from thrsim.config import BoneMaterial, JohnsonCookDamage, JohnsonCookHardening
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.tet_metrics import minimum_altitudes
from thrsim.physics.material import characteristic_length, damage_initiation_increment, jc_radial_return
from thrsim.physics.tet_kinematics import MassScaling, lumped_nodal_mass, mass_scaling, node_element_csr, shape_gradients

#: ABAQUS/Explicit's default linear bulk viscosity coefficient: damps ringing at contact impacts
LINEAR_BULK_VISCOSITY = 0.06


@njit(parallel=True, cache=True)
def element_update(
    tets, grads, volume, char_length, bulk_viscosity, active, du, dt,
    stress, peeq, damage, initiation, plastic_work, damage_work, element_force,
    lam, mu, a, b, n, c, rate0, d1, d2, d3, d4, u_f,
):  # fmt: skip
    """Advance every active element's stress by one step and write its nodal forces.

    Returns the number of elements deleted during this step (their ``active`` flag is cleared
    and their forces zeroed).
    """
    n_elements = len(volume)
    deleted = 0
    poisson = lam / (2.0 * (lam + mu))
    youngs = mu * (3.0 * lam + 2.0 * mu) / (lam + mu)
    for e in prange(n_elements):
        if active[e] == 0:
            continue
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
        dpeeq = jc_radial_return(q_trial, peeq[e], dt, mu, a, b, n, c, rate0) if q_trial > 0.0 else 0.0
        if dpeeq > 0.0:
            factor = 1.0 - 3.0 * mu * dpeeq / q_trial
            dxx *= factor
            dyy *= factor
            dzz *= factor
            sxy *= factor
            syz *= factor
            szx *= factor
            q_new = factor * q_trial
            sxx, syy, szz = dxx + pressure, dyy + pressure, dzz + pressure
            peeq[e] += dpeeq
            plastic_work[e] += (1.0 - damage[e]) * q_new * dpeeq * volume[e]
            if initiation[e] < 1.0:
                initiation[e] += damage_initiation_increment(dpeeq, pressure / q_new, dpeeq / dt, d1, d2, d3, d4, rate0)
            else:
                grown = min(1.0, damage[e] + char_length[e] * dpeeq / u_f) - damage[e]
                damage[e] += grown
                # strain energy released as the stiffness degrades: ΔD·½σ̄:C⁻¹:σ̄·V
                contracted = sxx * sxx + syy * syy + szz * szz + 2.0 * (sxy * sxy + syz * syz + szx * szx)
                trace_s = sxx + syy + szz
                energy_density = ((1.0 + poisson) * contracted - poisson * trace_s * trace_s) / (2.0 * youngs)
                damage_work[e] += grown * energy_density * volume[e]
        stress[e, 0] = sxx
        stress[e, 1] = syy
        stress[e, 2] = szz
        stress[e, 3] = sxy
        stress[e, 4] = syz
        stress[e, 5] = szx
        if damage[e] >= 1.0:
            active[e] = 0
            deleted += 1
            for k in range(4):
                for i in range(3):
                    element_force[e, k, i] = 0.0
            continue
        keep = 1.0 - damage[e]
        viscous = bulk_viscosity[e] * trace / dt
        txx = keep * sxx + viscous
        tyy = keep * syy + viscous
        tzz = keep * szz + viscous
        txy, tyz, tzx = keep * sxy, keep * syz, keep * szx
        v = volume[e]
        for k in range(4):
            gx, gy, gz = grads[e, k, 0], grads[e, k, 1], grads[e, k, 2]
            element_force[e, k, 0] = -v * (txx * gx + txy * gy + tzx * gz)
            element_force[e, k, 1] = -v * (txy * gx + tyy * gy + tyz * gz)
            element_force[e, k, 2] = -v * (tzx * gx + tyz * gy + tzz * gz)
    return deleted


@njit(parallel=True, cache=True)
def node_update(offsets, entries, element_force, external_force, support_stiffness, inverse_mass, held, velocity, displacement, du, dt):
    """Central difference: v(n+½) = v(n−½) + Δt·M⁻¹(f_ext − f_int − k·u), u(n+1) = u(n) + Δt·v(n+½).

    ``held`` nodes (the encastre) and orphaned nodes (inverse mass 0) do not move;
    ``support_stiffness`` ties nodes elastically to their rest positions (0: no spring).
    """
    for node in prange(len(inverse_mass)):
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
def account_deletions(active, accounted, tets, element_mass, velocity, nodal_mass, inverse_mass, elements_at_node, debris):
    """Take newly deleted elements' mass off their nodes; freeze nodes left with no element.

    The debris carries its share of the nodes' momentum and kinetic energy out of the model:
    ``debris`` accumulates [mass, px, py, pz, kinetic energy, count] so momentum and energy
    can be balanced across deletion.
    """
    for e in range(len(active)):
        if active[e] != 0 or accounted[e]:
            continue
        accounted[e] = True
        share = element_mass[e] / 4.0
        debris[5] += 1.0
        for k in range(4):
            node = tets[e, k]
            vx, vy, vz = velocity[node, 0], velocity[node, 1], velocity[node, 2]
            debris[0] += share
            debris[1] += share * vx
            debris[2] += share * vy
            debris[3] += share * vz
            debris[4] += 0.5 * share * (vx * vx + vy * vy + vz * vz)
            nodal_mass[node] -= share
            elements_at_node[node] -= 1
            if elements_at_node[node] == 0:
                nodal_mass[node] = 0.0
                velocity[node, 0] = 0.0
                velocity[node, 1] = 0.0
                velocity[node, 2] = 0.0
            inverse_mass[node] = 1.0 / nodal_mass[node] if nodal_mass[node] > 0.0 else 0.0


@njit(cache=True)
def solid_step(
    tets, grads, volume, char_length, bulk_viscosity, active, du, dt,
    stress, peeq, damage, initiation, plastic_work, damage_work, element_force,
    lam, mu, a, b, n, c, rate0, d1, d2, d3, d4, u_f,
    accounted, element_mass, nodal_mass, elements_at_node, debris,
    offsets, entries, external_force, support_stiffness, inverse_mass, held, velocity, displacement,
):  # fmt: skip
    """One central-difference step of the solid: stresses, deletions, then nodes. Returns deletions."""
    deleted = element_update(
        tets, grads, volume, char_length, bulk_viscosity, active, du, dt,
        stress, peeq, damage, initiation, plastic_work, damage_work, element_force,
        lam, mu, a, b, n, c, rate0, d1, d2, d3, d4, u_f,
    )  # fmt: skip
    if deleted > 0:
        account_deletions(active, accounted, tets, element_mass, velocity, nodal_mass, inverse_mass, elements_at_node, debris)
    node_update(offsets, entries, element_force, external_force, support_stiffness, inverse_mass, held, velocity, displacement, du, dt)
    return deleted


def von_mises(stress: np.ndarray) -> np.ndarray:
    """Von Mises equivalent of Voigt stresses (…, 6)."""
    s = np.asarray(stress)
    p = s[..., :3].mean(axis=-1, keepdims=True)
    dev = s[..., :3] - p
    return np.sqrt(1.5 * ((dev**2).sum(axis=-1) + 2.0 * (s[..., 3:] ** 2).sum(axis=-1)))


class ExplicitSolid:
    """A damaging JC solid on a tet mesh, advanced by central differences at a fixed step.

    ``target_dt_s`` sets the step reached by per-element mass scaling (None: the unscaled
    Courant step). ``held`` nodes default to the mesh's fixed nodes.
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
    ) -> None:
        self.mesh = mesh
        self.material, self.hardening, self.damage_law = material, hardening, damage
        nodes, tets = mesh.nodes, mesh.tets
        self.tets = tets.astype(np.int64)
        self.grads = shape_gradients(nodes, self.tets)
        self.volume = np.abs(mesh.volumes)
        self.char_length = characteristic_length(self.volume)
        self.lam, self.mu = material.lame_lambda_pa, material.shear_modulus_pa
        p_wave = self.lam + 2.0 * self.mu
        self.scaling: MassScaling = mass_scaling(nodes, self.tets, material.density_kg_m3, p_wave, target_dt_s, safety)
        self.dt = float(target_dt_s) if target_dt_s is not None else self.scaling.stable_dt_s
        if self.dt > self.scaling.stable_dt_s * (1 + 1e-9):
            raise ValueError(f"time step {self.dt:.3g} s exceeds the stable step {self.scaling.stable_dt_s:.3g} s")
        rho = self.scaling.element_density
        self.element_mass = rho * self.volume
        self.physical_element_mass = material.density_kg_m3 * self.volume
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
        self.element_force = np.zeros((n_el, 4, 3))
        self.external_force = np.zeros((n_nodes, 3))
        # what deleted elements took with them: [mass, momentum (3), kinetic energy, count]
        self.debris = np.zeros(6)
        self.detached_count = 0
        self._accounted = np.zeros(n_el, dtype=np.bool_)

    @property
    def alive_nodes(self) -> np.ndarray:
        """Nodes still attached to at least one active element."""
        return self.inverse_mass > 0.0

    def kernel_arguments(self) -> tuple:
        """The solid's arrays and constants in :func:`solid_step`'s order, external force last-but-six."""
        j, d = self.hardening, self.damage_law
        return (
            self.tets, self.grads, self.volume, self.char_length, self.bulk_viscosity_coefficient, self.active, self.du, self.dt,
            self.stress, self.peeq, self.damage, self.initiation, self.plastic_work, self.damage_work, self.element_force,
            self.lam, self.mu, j.a_pa, j.b_pa, j.n, j.c, j.reference_strain_rate_s,
            d.d1, d.d2, d.d3, d.d4, d.displacement_at_failure_m,
            self._accounted, self.element_mass, self.nodal_mass, self.elements_at_node, self.debris,
            self.offsets, self.entries,
        )  # fmt: skip

    def step(self, external_force: np.ndarray | None = None) -> int:
        """One central-difference step; returns how many elements were deleted in it."""
        force = self.external_force if external_force is None else external_force
        deleted = solid_step(
            *self.kernel_arguments(), force, self.support_stiffness, self.inverse_mass, self.held, self.velocity, self.displacement
        )
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
            self.active[detached] = 0
            self.damage[detached] = 1.0
            self.detached_count += count
            account_deletions(
                self.active, self._accounted, self.tets, self.element_mass, self.velocity,
                self.nodal_mass, self.inverse_mass, self.elements_at_node, self.debris,
            )  # fmt: skip
        return count

    def von_mises(self) -> np.ndarray:
        """Von Mises stress of the (damaged) Cauchy stress, 0 for deleted elements, Pa."""
        return np.where(self.active > 0, (1.0 - self.damage) * von_mises(self.stress), 0.0)

    def kinetic_energy(self) -> float:
        return float(0.5 * (self.nodal_mass * (self.velocity**2).sum(axis=1)).sum())

    def momentum(self) -> np.ndarray:
        return (self.nodal_mass[:, None] * self.velocity).sum(axis=0)

    def elastic_energy(self) -> float:
        """Σ (1 − D)·½ σ̄:C⁻¹:σ̄·V over active elements, plus the support springs' ½ k u²."""
        e, nu = self.material.youngs_modulus_pa, self.material.poisson_ratio
        s = self.stress
        contracted = (s[:, :3] ** 2).sum(axis=1) + 2.0 * (s[:, 3:] ** 2).sum(axis=1)
        density = ((1 + nu) * contracted - nu * s[:, :3].sum(axis=1) ** 2) / (2.0 * e)
        keep = np.where(self.active > 0, 1.0 - self.damage, 0.0)
        springs = 0.5 * (self.support_stiffness * (self.displacement**2).sum(axis=1))[self.alive_nodes].sum()
        return float((keep * density * self.volume).sum() + springs)

    def plastic_dissipation(self) -> float:
        return float(self.plastic_work.sum())

    def damage_dissipation(self) -> float:
        """Strain energy released by stiffness degradation (ABAQUS's ALLDMD)."""
        return float(self.damage_work.sum())

    def internal_energy(self) -> float:
        """Elastic strain energy + plastic dissipation + damage dissipation (ABAQUS's ALLIE)."""
        return self.elastic_energy() + self.plastic_dissipation() + self.damage_dissipation()
