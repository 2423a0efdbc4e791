"""A single linear tet driven through a prescribed strain path by the solver's own element kernel.

The element kernel :func:`thrsim.physics.explicit.element_update` (strain increment from the
reference gradients, elastic trial, JC radial return, damage, deletion) is called exactly as
the solver calls it, with nodal displacement increments Δu_a = Δε·X_a that make the element's
strain increment exactly Δε. Strain paths are quasi-static (no inertia): each increment has
its own dt so that the strain rate is the one asked for.

Uniaxial stress is reached by a lateral stress-free iteration: the two lateral strain
increments (equal, by isotropy) are solved with Brent's method so that the lateral stress
after the return is zero to round-off.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq

from thrsim.config import BoneMaterial, CrushableFoam, JohnsonCookDamage, JohnsonCookHardening
from thrsim.geometry.tet_metrics import signed_volumes
from thrsim.physics.explicit import MaterialConstants, SolidArrays, Tissue, element_update
from thrsim.physics.material import characteristic_length
from thrsim.physics.tet_kinematics import shape_gradients

#: a positively oriented, moderately irregular tet (m) with edges about 1 mm
REFERENCE_TET = np.array([[0.0, 0.0, 0.0], [1.1e-3, 0.1e-3, 0.0], [0.2e-3, 0.9e-3, 0.1e-3], [0.15e-3, 0.2e-3, 1.0e-3]])


class SingleTet:
    """State of one element and a way to try or commit a strain increment."""

    def __init__(
        self,
        material: BoneMaterial,
        hardening: JohnsonCookHardening,
        damage: JohnsonCookDamage,
        nodes: np.ndarray = REFERENCE_TET,
        compaction: CrushableFoam | None = None,
    ) -> None:
        self.nodes = np.asarray(nodes, dtype=float)
        self.tets = np.array([[0, 1, 2, 3]], dtype=np.int64)
        self.grads = shape_gradients(self.nodes, self.tets)
        self.volume = np.abs(signed_volumes(self.nodes, self.tets))
        self.char_length = characteristic_length(self.volume)
        self.material, self.hardening, self.damage_law = material, hardening, damage
        self.tissue = Tissue(material, hardening, damage, compaction)
        self.lam, self.mu = material.lame_lambda_pa, material.shear_modulus_pa
        self.stress = np.zeros((1, 6))
        self.peeq = np.zeros(1)
        self.damage = np.zeros(1)
        self.initiation = np.zeros(1)
        self.plastic_work = np.zeros(1)
        self.active = np.ones(1, dtype=np.uint8)
        self.strain = np.zeros((3, 3))

    def _state(self) -> tuple:
        return self.stress, self.peeq, self.damage, self.initiation, self.plastic_work, self.active

    def apply(self, deps: np.ndarray, dt: float, commit: bool) -> tuple[np.ndarray, float, float, bool]:
        """Stress (Voigt, effective), PEEQ, damage and active flag after the increment ``deps``."""
        state = self._state() if commit else tuple(a.copy() for a in self._state())
        stress, peeq, damage, initiation, work, active = state
        du = self.nodes @ np.asarray(deps, dtype=float).T  # Δu_a = Δε·X_a (Δε symmetric)
        one, nodes4 = np.zeros(1), np.zeros((4, 3))
        arrays = SolidArrays(
            tets=self.tets, zone_elements=np.arange(1), zone_nodes=np.arange(4), contact_nodes=np.arange(4),
            material=np.zeros(1, dtype=np.int64), grads=self.grads, volume=self.volume, char_length=self.char_length, bulk_viscosity=one.copy(),
            offsets=np.zeros(5, dtype=np.int64), entries=np.zeros(4, dtype=np.int64),
            support_stiffness=np.zeros(4), held=np.zeros(4, dtype=np.bool_), active=active,
            accounted=np.zeros(1, dtype=np.bool_), stress=stress, peeq=peeq, damage=damage, initiation=initiation,
            plastic_work=work, damage_work=one.copy(), viscous_work=one.copy(), viscous_pressure=one.copy(),
            static_flow_stress=one.copy(), static_flow_peeq=np.full(1, np.nan), element_force=np.zeros((1, 4, 3)),
            nodal_mass=np.zeros(4), inverse_mass=np.zeros(4), elements_at_node=np.ones(4, dtype=np.int64),
            velocity=nodes4.copy(), displacement=nodes4.copy(), du=du, external_force=nodes4.copy(),
            cutting_damage=np.zeros(4), debris=np.zeros(7),
        )  # fmt: skip
        constants = MaterialConstants.of(dt, [self.tissue])
        element_update(arrays, constants)
        if commit:
            self.strain = self.strain + deps
        return stress[0].copy(), float(peeq[0]), float(damage[0]), bool(active[0])

    def uniaxial_stress_increment(self, d_axial: float, dt: float) -> float:
        """Commit an axial (x) strain increment with stress-free lateral faces; returns the lateral
        strain increment found."""

        def lateral_stress(b: float) -> float:
            s, *_ = self.apply(np.diag([d_axial, b, b]), dt, commit=False)
            return 0.5 * (s[1] + s[2])

        lo, hi = -abs(d_axial), abs(d_axial)
        f_lo, f_hi = lateral_stress(lo), lateral_stress(hi)
        if f_lo * f_hi > 0:  # should not happen for isotropic elasticity with ν < 0.5
            raise RuntimeError("lateral stress-free iteration could not bracket the root")
        b = brentq(lateral_stress, lo, hi, xtol=1e-18, rtol=4 * np.finfo(float).eps, maxiter=200)
        self.apply(np.diag([d_axial, b, b]), dt, commit=True)
        return b

    def shear_increment(self, d_gamma: float, dt: float) -> None:
        """Commit an engineering shear strain increment Δγ_xy (isochoric, triaxiality 0)."""
        deps = np.zeros((3, 3))
        deps[0, 1] = deps[1, 0] = 0.5 * d_gamma
        self.apply(deps, dt, commit=True)


def graded_increments(total: float, first: float, largest: float, growth: float = 1.05) -> np.ndarray:
    """Increments starting at ``first`` and growing geometrically up to ``largest``, summing to ``total``."""
    steps = []
    step, done = first, 0.0
    while done < total:
        step = min(step, largest, total - done)
        steps.append(step)
        done += step
        step *= growth
    return np.array(steps)
