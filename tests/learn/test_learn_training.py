"""Training on real solver output, deterministic resume, and the model directory on disk."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from learn_helpers import tiny_settings

from thrsim.errors import ThrsimInputError
from thrsim.learn.cases import load_cases
from thrsim.learn.graph import StaticGraph
from thrsim.learn.model_dir import CARD, MESH, load_model
from thrsim.learn.rollout import LearnedStep, rollout
from thrsim.learn.training import Trainer


def _trainer(cases, settings):
    mesh = cases[0]
    return Trainer(StaticGraph(mesh), cases[1], [], settings, 0.3)


@pytest.fixture(scope="module")
def real(real_case):
    mesh, cases = load_cases(real_case)
    for case in cases:
        case.split = "train"
    return mesh, cases


def _entropy(target: torch.Tensor, mask: torch.Tensor) -> float:
    """The least cross-entropy soft targets allow: their mean binary entropy on the masked nodes."""
    q = target[mask].double().clamp(1e-12, 1 - 1e-12)
    return float(-(q * q.log() + (1 - q) * (1 - q).log()).mean())


def test_training_lowers_the_loss_on_a_real_case(real):
    settings = tiny_settings(
        epochs=8, max_samples_per_epoch=None, learning_rate=1e-2, final_learning_rate=1e-3, alpha_noise=0.0, position_noise_mm=0.0
    )
    trainer = _trainer(real, settings)
    inputs, alpha_next, damage_next = trainer._batch([trainer._sample(i, None) for i in range(len(trainer.samples))])
    mask = trainer.gn.trainable_mask(inputs)
    # α and D are soft targets: the loss cannot fall below their entropy, so the excess over it is what training must lower
    floor = _entropy(alpha_next, mask) + _entropy(damage_next, mask)

    def excess() -> float:
        with torch.no_grad():
            return float(trainer.gn.loss(inputs, alpha_next, damage_next)) - floor

    before = excess()
    losses = [trainer.train_epoch()[0] for _ in range(settings.train.epochs)]
    assert np.mean(losses[-2:]) < np.mean(losses[:2]), losses
    assert excess() < 0.9 * before, (before, excess())


@pytest.mark.parametrize(("damage_noise", "damage_is_noisy"), [(None, True), (0.0, False)], ids=["as_alpha", "none"])
def test_the_noise_on_input_damage_is_set_apart_from_alphas(real, damage_noise, damage_is_noisy):
    trainer = _trainer(real, tiny_settings(alpha_noise=0.05, damage_noise=damage_noise, position_noise_mm=0.0))
    index = int(np.argmax([trainer.train_cases[c].damage[t].max() for c, t in trainer.samples]))  # a pair with damaged bone
    (sub, alpha_in, _), damage_in, *_ = trainer._sample(index, np.random.default_rng(3))
    case_index, t = trainer.samples[index]
    case = trainer.train_cases[case_index]
    active = case.alpha[t][sub.nodes] >= trainer.threshold
    assert not np.allclose(alpha_in[active], case.alpha[t][sub.nodes][active])
    assert np.allclose(damage_in[active], case.damage[t][sub.nodes][active]) != damage_is_noisy


@pytest.mark.parametrize("pushforward", [{}, {"pushforward_steps": 2, "pushforward_from_epoch": 1}], ids=["one_step", "pushforward"])
def test_resumed_training_matches_an_uninterrupted_run(real, tmp_path, pushforward):
    settings = tiny_settings(epochs=2, **pushforward)
    straight = _trainer(real, settings)
    straight.run(None)
    first = _trainer(real, settings)  # the same run, cut after its first epoch
    first.train_epoch()
    first.history.append({"epoch": 1, "seconds": 0.0})
    first.save_checkpoint(tmp_path / "ckpt")
    resumed = _trainer(real, settings)
    assert resumed.load_checkpoint(tmp_path / "ckpt")
    assert resumed.epoch == 1
    resumed.run(None)
    for (name, a), (_, b) in zip(straight.gn.state_dict().items(), resumed.gn.state_dict().items(), strict=True):
        assert torch.equal(a, b), name
    for (name, a), (_, b) in zip(straight.mlp.state_dict().items(), resumed.mlp.state_dict().items(), strict=True):
        assert torch.equal(a, b), name


def test_pushforward_feeds_the_networks_own_rollout_from_its_first_epoch(real):
    settings = tiny_settings(epochs=2, pushforward_steps=3, pushforward_fraction=1.0, pushforward_from_epoch=1)
    trainer = _trainer(real, settings)
    rng = np.random.default_rng(0)
    assert trainer._pushed_steps(5, rng) == 0  # before pushforward_from_epoch: ground truth
    trainer.train_epoch()
    assert trainer._pushed_steps(0, rng) == 0  # nothing before the first frame
    assert {trainer._pushed_steps(5, rng) for _ in range(200)} == {1, 2, 3}
    assert {trainer._pushed_steps(1, rng) for _ in range(20)} == {1}
    case = trainer.train_cases[0]
    t = case.frames - 2
    state = trainer._pushed_state(case, t, 3)
    pushed = state.alpha
    assert trainer.gn.training
    assert (pushed[case.alpha[t - 3] < 0.3] < 0.3).all()  # removed bone stays removed
    region_changed = pushed != case.alpha[t - 3]
    assert region_changed.any() and not np.array_equal(pushed, case.alpha[t])
    assert np.all(state.damage >= case.damage[t - 3]) and not np.array_equal(state.damage, case.damage[t - 3])  # D pushed forward too


def test_a_checkpoint_of_another_run_is_refused(real, tmp_path):
    trainer = _trainer(real, tiny_settings(epochs=1))
    trainer.save_checkpoint(tmp_path / "ckpt")
    other = _trainer(real, tiny_settings(epochs=1, seed=7))
    with pytest.raises(ThrsimInputError, match="another training run"):
        other.load_checkpoint(tmp_path / "ckpt")
    assert not _trainer(real, tiny_settings(epochs=1)).load_checkpoint(tmp_path / "none")


def _rollout_alpha(model, cases):
    step = LearnedStep(model.gn, model.graph, model.settings.features, model.teeth_radius_m)
    out = []
    for case in cases:
        masks, centres = rollout(step, case, 0, case.frames - 1, model.threshold, model.reamer_feed())
        out.append((np.array(masks), centres))
    return out


def test_model_directory_roundtrip_predicts_bit_for_bit(tiny_model, synthetic_dataset, tmp_path):
    model = load_model(tiny_model)
    card = json.loads((tiny_model / CARD).read_text())
    assert card["format"] == "thrsim-model" and card["data"]["split"]["train"]
    assert {"settings", "metrics", "versions", "training", "advance", "mesh", "data"} <= set(card)
    assert card["training"]["network_seconds"] > 0 and card["mesh"]["elements"] == model.mesh.n_tets
    low, high = model.trained_force_n  # the push the reaming trainer calls out of range beyond
    assert 0 < low <= high and [low, high] == card["data"]["force_range_n"]
    copy = tmp_path / "copy"
    shutil.copytree(tiny_model, copy)
    again = load_model(copy)
    _, cases = load_cases(synthetic_dataset, splits=("test",))
    for (m1, c1), (m2, c2) in zip(_rollout_alpha(model, cases), _rollout_alpha(again, cases), strict=True):
        assert np.array_equal(m1, m2) and np.array_equal(c1, c2)
    for name, tensor in model.gn.state_dict().items():
        assert torch.equal(tensor, again.gn.state_dict()[name])


def test_model_directories_that_do_not_fit_are_refused(tiny_model, real_case, tmp_path):
    real_mesh, _ = load_cases(real_case)
    with pytest.raises(ThrsimInputError, match="another mesh"):
        load_model(tiny_model, expect_mesh=real_mesh)
    with pytest.raises(ThrsimInputError, match="no such model directory"):
        load_model(tmp_path / "missing")
    with pytest.raises(ThrsimInputError, match="not a thrsim model directory"):
        load_model(tmp_path)
    old = tmp_path / "old"
    shutil.copytree(tiny_model, old)
    card = json.loads((old / CARD).read_text())
    card["format_version"] = 99
    (old / CARD).write_text(json.dumps(card))
    with pytest.raises(ThrsimInputError, match="incompatible"):
        load_model(old)
    mixed = tmp_path / "mixed"
    shutil.copytree(tiny_model, mixed)
    from safetensors.numpy import save_file

    from thrsim.learn.model_dir import mesh_arrays

    save_file(mesh_arrays(real_mesh), str(mixed / MESH))
    with pytest.raises(ThrsimInputError, match="digest"):
        load_model(mixed)


def test_a_learning_pack_trains_the_same_cases_as_its_dataset(tiny_model, synthetic_dataset, tmp_path):
    from thrsim.data.pack import write_pack
    from thrsim.learn.pipeline import train_model

    pack = tmp_path / "learning.h5"
    write_pack(synthetic_dataset, pack)
    card = train_model(pack, tmp_path / "from-pack", tiny_settings(epochs=1))
    from_dataset = json.loads((tiny_model / CARD).read_text())
    assert card["data"]["form"].startswith("learning pack") and from_dataset["data"]["form"] == "case files"
    assert card["data"]["digest"] == from_dataset["data"]["digest"]  # the source cases' digests
    assert card["data"]["split"] == from_dataset["data"]["split"] and card["data"]["frame_pairs"] == from_dataset["data"]["frame_pairs"]
    assert card["data"]["source"] == str(pack)


def test_a_model_with_damage_refuses_cases_that_do_not_record_it(real):
    import dataclasses

    mesh, cases = real
    assert all(case.damage is not None for case in cases)  # the solver records damage
    undamaged = [dataclasses.replace(case, damage=None) for case in cases]
    with pytest.raises(ThrsimInputError, match="do not record damage") as refused:
        _trainer((mesh, undamaged), tiny_settings())
    assert "\n" not in str(refused.value)
    settings = tiny_settings()
    without = settings.model_copy(update={"features": settings.features.model_copy(update={"damage": False})})
    assert _trainer((mesh, undamaged), without).train_epoch()[0] > 0  # a model without damage trains on them
