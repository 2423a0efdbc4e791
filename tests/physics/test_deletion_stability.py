"""Deleting elements never destabilises the explicit step: a node keeps its mass until its last element goes."""

from __future__ import annotations

import numpy as np
import pytest

from thrsim.physics.tet_kinematics import lumped_nodal_mass
from thrsim.verification.bookkeeping import eroded_block, eroded_energy_history


@pytest.mark.parametrize("seed", [1, 2])
def test_an_eroded_elastic_block_keeps_its_energy(seed):
    """With two thirds of the elements gone many nodes hang on one element; undamped and elastic, the
    booked energy stays near its start and does not grow."""
    assert int(np.sum(eroded_block(seed, 1.0 / 3.0).elements_at_node == 1)) > 10
    history = eroded_energy_history(seed)
    assert np.isfinite(history).all() and history.max() < 1.3
    assert history[-500:].max() <= 1.02 * history[:500].max()


def test_the_old_rule_of_taking_each_deleted_elements_quarter_runs_away():
    """The check can fail: priced at their remaining elements' mass, lone nodes run away."""
    solid = eroded_block(1, 1.0 / 3.0)
    alive = solid.active > 0
    mass = lumped_nodal_mass(len(solid.nodal_mass), solid.tets[alive], solid.element_mass[alive])
    solid.nodal_mass[:] = mass
    solid.inverse_mass[:] = np.where(mass > 0, 1.0 / np.maximum(mass, 1e-300), 0.0)
    start = solid.kinetic_energy() + solid.elastic_energy()
    for _ in range(1000):
        solid.step()
    assert not solid.kinetic_energy() + solid.elastic_energy() < 100 * start


def test_a_node_takes_its_whole_mass_with_its_last_element():
    solid = eroded_block(4, kept_fraction=1.0)
    total = float(solid.nodal_mass.sum())
    intact = solid.nodal_mass.copy()
    solid.remove_elements(np.random.default_rng(4).random(solid.mesh.n_tets) > 0.5)
    attached = solid.elements_at_node > 0
    assert np.array_equal(solid.nodal_mass[attached], intact[attached])
    assert not solid.nodal_mass[~attached].any() and not solid.inverse_mass[~attached].any()
    assert float(solid.nodal_mass.sum()) == pytest.approx(total - float(intact[~attached].sum()), rel=1e-12)
