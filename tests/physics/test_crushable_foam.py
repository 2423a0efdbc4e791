"""The cancellous bone's crushable foam: its return mapping, and crushing that compacts, not fractures."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from thrsim.config import BoneMaterial, CancellousBone, JohnsonCookDamage, JohnsonCookHardening
from thrsim.physics.material import crushed_flow_stress, foam_return
from thrsim.verification.single_element import SingleTet

BONE = CancellousBone()
FOAM = BONE.compaction
ALPHA = FOAM.yield_ellipse_alpha
BETA = math.sqrt(1.0 + ALPHA**2 / 9.0)
EPS_D = FOAM.densification_strain(BONE.material.density_kg_m3)
HARDENING = (BONE.hardening.a_pa, BONE.hardening.b_pa, BONE.hardening.n, BONE.hardening.c, BONE.hardening.reference_strain_rate_s)
CAP = FOAM.densified_flow_stress_pa
DENSIFY = (EPS_D, FOAM.densification_coefficient, FOAM.densification_exponent, CAP)
SHEAR, BULK = BONE.material.shear_modulus_pa, BONE.material.bulk_modulus_pa
DT = 4e-6


def test_alpha_and_densification_strain_follow_their_closed_forms() -> None:
    assert ALPHA == 3.0 / math.sqrt(2.0)  # plastic Poisson ratio 0
    assert math.isclose(EPS_D, 1.0 - 1.4 * 500.0 / 1900.0)
    # plateau until (1/D)(ε_D/(ε_D − ε̂))^m reaches 1, then rising toward ε_D up to the tissue's strength
    onset = EPS_D * (1.0 - 1.0 / FOAM.densification_coefficient)
    plateau = crushed_flow_stress(onset * 0.99, 0.0, *HARDENING, *DENSIFY)
    assert plateau < 10e6 and crushed_flow_stress(0.9 * EPS_D, 0.0, *HARDENING, *DENSIFY) > 2 * plateau
    assert crushed_flow_stress(0.999 * EPS_D, 0.0, *HARDENING, *DENSIFY) == CAP == crushed_flow_stress(2.0, 0.0, *HARDENING, *DENSIFY)


@settings(max_examples=300, deadline=None)
@given(
    q_trial=st.floats(0.0, 200e6),
    mean_trial=st.floats(-200e6, 200e6),
    peeq=st.floats(0.0, 1.0),
)
def test_the_return_lands_on_the_yield_surface(q_trial: float, mean_trial: float, peeq: float) -> None:
    static = crushed_flow_stress(peeq, 0.0, *HARDENING, *DENSIFY)
    gamma, dpeeq = foam_return(q_trial, mean_trial, peeq, static, DT, SHEAR, BULK, ALPHA, *HARDENING, *DENSIFY)
    f_trial = math.hypot(q_trial, ALPHA * mean_trial)
    if f_trial <= BETA * static:
        assert (gamma, dpeeq) == (0.0, 0.0)
        return
    assert gamma > 0.0 and dpeeq > 0.0
    q = q_trial / (1.0 + 6.0 * SHEAR * gamma)
    mean = mean_trial / (1.0 + 2.0 * BULK * ALPHA**2 * gamma)
    f = math.hypot(q, ALPHA * mean)
    assert math.isclose(f, BETA * crushed_flow_stress(peeq + dpeeq, dpeeq / DT, *HARDENING, *DENSIFY), rel_tol=1e-9)
    assert math.isclose(dpeeq, 2.0 * BETA * gamma * f, rel_tol=1e-12)  # Δε̂ = σ:Δεᵖ / σ_c


def _confined_compression(compaction, axial_strain: float) -> SingleTet:
    """Uniaxial strain (the bone under the subchondral plate) in steps of 0.2 %."""
    element = SingleTet(BONE.material, BONE.hardening, BONE.damage, compaction=compaction)
    for _ in range(round(axial_strain / 2e-3)):
        element.apply(np.diag([-2e-3, 0.0, 0.0]), 2e-3 / 1e-4, commit=True)
        if not element.active[0]:
            break
    return element


def test_crushing_compacts_where_von_mises_fractures() -> None:
    foam = _confined_compression(FOAM, 0.6)
    assert foam.active[0] and foam.initiation[0] == 0.0 and foam.damage[0] == 0.0
    assert 0.4 < foam.peeq[0] < EPS_D
    # densified: the axial stress has risen well past the plateau
    assert -foam.stress[0, 0] > 3 * BONE.hardening.a_pa
    von_mises = _confined_compression(None, 0.9)  # its plastic strain is 2/3 of the axial
    assert von_mises.initiation[0] >= 1.0 and von_mises.damage[0] > 0.0


def test_fully_dense_bone_is_no_stronger_than_the_tissue_and_fractures() -> None:
    foam = _confined_compression(FOAM, 1.5)
    beta = math.sqrt(1.0 + ALPHA**2 / 9.0)
    mean = foam.stress[0, :3].mean()
    deviator = foam.stress[0, :3] - mean
    q = math.sqrt(1.5 * (deviator @ deviator))
    assert math.hypot(q, ALPHA * mean) <= beta * CAP * (1 + 1e-9)
    assert foam.initiation[0] > 0.0


def test_the_foam_still_fractures_in_shear() -> None:
    element = SingleTet(BONE.material, BONE.hardening, BONE.damage, compaction=FOAM)
    for _ in range(400):
        element.shear_increment(4e-3, 4e-3 / 1e-4)
        if element.initiation[0] >= 1.0:
            break
    assert element.initiation[0] >= 1.0 and element.peeq[0] < EPS_D


def test_the_flow_stress_each_element_keeps_is_the_one_computed_afresh() -> None:
    """The solid keeps each element's flow stress at rest until its plastic strain changes (most
    elements with plastic history stay elastic step after step); stepping with it is bit for bit
    stepping with it recomputed every step, in cortical and cancellous bone, and a plastic strain
    changed from outside (a carried state) is picked up."""
    from thrsim.geometry.box_mesh import box_mesh
    from thrsim.geometry.mesh import TetMesh
    from thrsim.physics.explicit import ExplicitSolid, Tissue

    box = box_mesh((4, 4, 4), (4e-3, 4e-3, 4e-3), fixed="zmin")
    lower = (box.centroids[:, 2] < 2e-3).astype(np.uint8)  # cancellous below, cortical above
    mesh = TetMesh(box.nodes, box.tets, box.node_sets, box.fixed_nodes, material=lower, material_names=("cortical", "cancellous"))
    solids = [
        ExplicitSolid(
            mesh,
            BoneMaterial(),
            JohnsonCookHardening(),
            JohnsonCookDamage(),
            target_dt_s=None,
            other_tissues={"cancellous": Tissue(BONE.material, BONE.hardening, BONE.damage, FOAM)},
        )
        for _ in range(2)
    ]
    top = np.flatnonzero(np.isclose(mesh.nodes[:, 2], mesh.nodes[:, 2].max()))
    for step in range(400):
        for kept, solid in enumerate(solids):
            solid.external_force[top, 2] = -60.0 * min(1.0, step / 200)
            if step == 300:
                solid.peeq[::7] += 0.01
            if not kept:
                solid.static_flow_peeq[:] = np.nan  # nothing kept: every return computes it afresh
            solid.step()
    fresh, kept_solid = solids
    for name in ("stress", "peeq", "damage", "initiation", "displacement", "velocity"):
        assert np.array_equal(getattr(fresh, name), getattr(kept_solid, name)), name
    yielded = kept_solid.peeq > 0.0
    assert yielded[lower == 0].any() and yielded[lower == 1].any()  # both returns ran
    assert np.isfinite(kept_solid.static_flow_peeq).sum() > 0
