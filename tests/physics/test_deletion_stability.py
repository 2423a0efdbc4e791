"""Deleting elements never destabilises the explicit step: a node keeps its mass until its last element goes."""

from __future__ import annotations

import numpy as np
import pytest

from thrsim.config import BoneMaterial, JohnsonCookDamage, JohnsonCookHardening
from thrsim.geometry.box_mesh import box_mesh
from thrsim.physics.explicit import ExplicitSolid
from thrsim.physics.tet_kinematics import mass_scaling


def _eroded_block(seed: int, kept_fraction: float) -> ExplicitSolid:
    """A jittered block mass-scaled to one step for every element (as the sockets are), most of its elements removed."""
    mesh = box_mesh((5, 5, 5), (2.5e-3, 2.5e-3, 2.5e-3), scheme="six", jitter=0.25, seed=seed)
    material = BoneMaterial()
    unscaled = mass_scaling(mesh.nodes, mesh.tets, material.density_kg_m3, material.lame_lambda_pa + 2 * material.shear_modulus_pa, None, 0.9)
    solid = ExplicitSolid(
        mesh, material, JohnsonCookHardening(a_pa=1e12), JohnsonCookDamage(), target_dt_s=4.0 * unscaled.stable_dt_s,
        held_nodes=np.zeros(0, dtype=np.int64), bulk_viscosity=0.0,
    )  # fmt: skip
    rng = np.random.default_rng(seed)
    solid.remove_elements(rng.random(mesh.n_tets) > kept_fraction)
    solid.velocity[solid.alive_nodes] = rng.normal(0.0, 1.0, (int(solid.alive_nodes.sum()), 3))
    return solid


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_an_eroded_elastic_block_keeps_its_energy(seed):
    """With most elements gone, many nodes hang on one element; undamped and elastic, the energy must stay
    what it was (with each deleted element's quarter taken off its nodes it grew 1e10-fold in 2,000 steps)."""
    solid = _eroded_block(seed, kept_fraction=0.35)
    lone = int(np.sum(solid.elements_at_node == 1))
    assert lone > 10
    start = solid.kinetic_energy() + solid.elastic_energy()
    energies = []
    for _ in range(2000):
        solid.step()
        energies.append(solid.kinetic_energy() + solid.elastic_energy())
    energies = np.array(energies) / start
    assert np.isfinite(energies).all()
    # the booked energy (kinetic at half steps) sits within a fifth of the start, and does not grow
    assert energies.max() < 1.3
    assert energies[-500:].max() <= 1.02 * energies[:500].max()

def test_a_node_takes_its_whole_mass_with_its_last_element():
    solid = _eroded_block(4, kept_fraction=1.0)
    total = float(solid.nodal_mass.sum())
    attached_mass = solid.nodal_mass.copy()
    solid.remove_elements(np.random.default_rng(4).random(solid.mesh.n_tets) > 0.5)
    attached = solid.elements_at_node > 0
    assert np.array_equal(solid.nodal_mass[attached], attached_mass[attached])
    assert not solid.nodal_mass[~attached].any() and not solid.inverse_mass[~attached].any()
    assert float(solid.nodal_mass.sum()) == pytest.approx(total - float(attached_mass[~attached].sum()), rel=1e-12)
