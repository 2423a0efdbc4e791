"""The cutoff triaxiality: bone compressed below it flows without damage; above it, damage as before."""

from __future__ import annotations

import numpy as np
import pytest

from thrsim.config import CancellousBone, JohnsonCookDamage
from thrsim.verification.single_element import SingleTet

BONE = CancellousBone()


def _strained(deps: np.ndarray, cutoff: float | None, steps: int = 400) -> SingleTet:
    element = SingleTet(BONE.material, BONE.hardening, BONE.damage.model_copy(update={"cutoff_triaxiality": cutoff}))
    for _ in range(steps):
        element.apply(deps, 1e-4, commit=True)
    return element


#: confined compression (ε_zz only): η well below −1/3; simple shear: η = 0
CONFINED = np.diag([0.0, 0.0, -0.004])
SHEAR = np.array([[0.0, 0.002, 0.0], [0.002, 0.0, 0.0], [0.0, 0.0, 0.0]])


def test_crushed_past_initiation_without_a_cutoff_the_bone_fails():
    element = _strained(CONFINED, None)
    assert element.peeq[0] > 0.5 and element.damage[0] > 0.0


def test_below_the_cutoff_the_bone_flows_without_damage():
    element = _strained(CONFINED, -1.0 / 3.0)
    assert element.peeq[0] > 0.5
    assert element.damage[0] == 0.0 and element.initiation[0] == 0.0 and element.active[0] == 1


@pytest.mark.parametrize("cutoff", [None, -1.0 / 3.0])
def test_above_the_cutoff_damage_is_unchanged(cutoff):
    reference, cut = _strained(SHEAR, None), _strained(SHEAR, cutoff)
    assert reference.damage[0] > 0.0 and cut.damage[0] == reference.damage[0] and cut.peeq[0] == reference.peeq[0]


def test_the_cutoff_is_absent_from_a_config_that_has_none():
    """Case files and checkpoints written before the field existed keep their configuration's hash."""
    assert "cutoff_triaxiality" not in JohnsonCookDamage().model_dump()
    assert JohnsonCookDamage(cutoff_triaxiality=-0.3).model_dump()["cutoff_triaxiality"] == -0.3
