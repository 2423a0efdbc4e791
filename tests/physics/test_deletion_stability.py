"""Deleting elements never destabilises the explicit step: a node keeps its mass until its last element goes.

That the eroded block keeps its energy is ``thrsim verify``'s ``deletion-stable-step`` (run by
tests/verification); here, that the figure can fail, and the mass rule itself.
"""

from __future__ import annotations

import numpy as np
import pytest

from thrsim.physics.tet_kinematics import lumped_nodal_mass
from thrsim.verification.bookkeeping import ERODED_ENERGY_TOLERANCE, eroded_block


def test_the_old_rule_of_taking_each_deleted_elements_quarter_runs_away():
    """Priced at their remaining elements' mass, nodes hanging on one element run away within 1,000 steps."""
    solid = eroded_block(1)
    alive = solid.active > 0
    mass = lumped_nodal_mass(len(solid.nodal_mass), solid.tets[alive], solid.element_mass[alive])
    solid.nodal_mass[:] = mass
    solid.inverse_mass[:] = np.where(mass > 0, 1.0 / np.maximum(mass, 1e-300), 0.0)
    start = solid.kinetic_energy() + solid.elastic_energy()
    for _ in range(1000):
        solid.step()
    assert not solid.kinetic_energy() + solid.elastic_energy() < 100 * (1.0 + ERODED_ENERGY_TOLERANCE) * start


def test_a_node_takes_its_whole_mass_with_its_last_element():
    solid = eroded_block(4, kept_fraction=1.0)
    total = float(solid.nodal_mass.sum())
    intact = solid.nodal_mass.copy()
    solid.remove_elements(np.random.default_rng(4).random(solid.mesh.n_tets) > 0.5)
    attached = solid.elements_at_node > 0
    assert np.array_equal(solid.nodal_mass[attached], intact[attached])
    assert not solid.nodal_mass[~attached].any() and not solid.inverse_mass[~attached].any()
    assert float(solid.nodal_mass.sum()) == pytest.approx(total - float(intact[~attached].sum()), rel=1e-12)
