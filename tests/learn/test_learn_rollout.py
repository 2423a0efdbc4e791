"""The learned step's bone state: α, the removal hazard accumulated over frames, and damage."""

from __future__ import annotations

import numpy as np
import torch

from thrsim.config import BonePatchConfig
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.learn.bench import untrained_model
from thrsim.learn.learned_simulator import REMOVAL_HAZARD
from thrsim.learn.rollout import BoneState, LearnedStep
from thrsim.learn.settings import preset
from thrsim.learn.simulator import start_position


def _step_with_hazard(hazard_per_step: float, damage_logit: float = 0.0) -> tuple[LearnedStep, np.ndarray, np.ndarray]:
    """A coarse-mesh step whose network keeps α and predicts the same removal hazard everywhere
    (and adds ``damage_logit`` to logit D)."""
    mesh = generate_bone_patch(BonePatchConfig(element_size_mm=1.0))
    model = untrained_model(mesh, preset("production"))
    removal_logit = float(np.log(np.expm1(hazard_per_step)))  # softplus⁻¹
    with torch.no_grad():
        model.gn.network.output.weight.zero_()
        model.gn.network.output.bias.copy_(torch.tensor([0.0, removal_logit, damage_logit]))
    axis = np.array([0.0, 0.0, -1.0])
    centre = start_position(mesh.nodes, axis, model.teeth_radius_m) + 0.3e-3 * axis
    return LearnedStep(model.gn, model.graph, model.settings.features, model.teeth_radius_m), centre, axis


def test_an_element_goes_when_its_accumulated_hazard_reaches_ln2():
    step, centre, axis = _step_with_hazard(0.3)  # 0.3, 0.6 < ln 2 ≤ 0.9
    state = BoneState.start(np.full(step.graph.centroids.shape[0], 0.9, dtype=np.float32))
    removed_at = []
    for _ in range(3):
        state = step(state, centre, axis, 230.0, 0.0, 136.0)
        removed_at.append(int((state.alpha < 0.3).sum()))
    alpha, hazard = state.alpha, state.hazard
    region = step.last.region
    assert region > 0
    assert removed_at[0] == removed_at[1] == 0
    assert removed_at[2] >= region  # the region of the third step, at least, is gone
    assert np.all(alpha[hazard >= REMOVAL_HAZARD] == 0.0)
    assert np.all(alpha[hazard == 0] == 0.9)  # outside every region: untouched


def test_without_hazard_nothing_is_removed_and_alpha_is_kept():
    step, centre, axis = _step_with_hazard(1e-6)
    state = BoneState.start(np.full(step.graph.centroids.shape[0], 0.9, dtype=np.float32))
    for _ in range(5):
        state = step(state, centre, axis, 230.0, 0.0, 136.0)
    assert not (state.alpha < 0.3).any() and np.allclose(state.alpha, 0.9, atol=1e-6)
    assert 0 < state.hazard.max() < 1e-5


def test_damage_is_carried_from_frame_to_frame_and_grows_only_in_the_region():
    step, centre, axis = _step_with_hazard(1e-6, damage_logit=1.0)
    start = BoneState.start(
        np.full(step.graph.centroids.shape[0], 0.9, dtype=np.float32), np.full(step.graph.centroids.shape[0], 0.1, dtype=np.float32)
    )
    state = step(start, centre, axis, 230.0, 0.0, 136.0)
    region = state.damage > 0.1
    assert region.sum() == step.last.region > 0
    later = step(state, centre, axis, 230.0, 0.0, 136.0)
    assert np.all(later.damage[region] > state.damage[region])  # read back and raised again
    assert np.all(later.damage[~region] == np.float32(0.1)) and np.all(start.damage == np.float32(0.1))  # the input state is not changed
