"""The physics a socket model's feed must obey, checked on a trained model (the reaction head).

No push, no cut and no advance; a reamer in free air cuts nothing and stops at the bone; more
push never removes less; a reamer pulled back cuts nothing. These hold by construction (the
reaction law's non-negative shares, the cut only while advancing), so they hold for any trained
model: here a tiny one trained on the synthetic dataset.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from learn_helpers import tiny_socket_settings

from thrsim.config import ReamerHoldConfig
from thrsim.errors import ThrsimInputError
from thrsim.learn.cases import load_cases
from thrsim.learn.graph import StaticGraph
from thrsim.learn.model_dir import load_model
from thrsim.learn.reaction_feed import ReactionFeed, feed_m_s
from thrsim.learn.reamer_feed import advance_to_support
from thrsim.learn.rollout import BoneState, LearnedStep, rollout


@pytest.fixture(scope="module")
def socket_model(tiny_socket_model):
    return load_model(tiny_socket_model)


@pytest.fixture(scope="module", params=["none", "cutting"])
def law_model(request, tiny_socket_model, tiny_prior_socket_model):
    """A trained socket model with each reaction prior: the physics holds whatever weights the law."""
    return load_model(tiny_socket_model if request.param == "none" else tiny_prior_socket_model)


@pytest.fixture(scope="module")
def case(synthetic_dataset):
    _, cases = load_cases(synthetic_dataset, splits=("test",))
    return cases[0]


def _parts(model, case):
    step = LearnedStep(model.gn, model.graph, model.settings.features, case.teeth_radius_m, case.element_cutting_energy_j_m3)
    margin_m = model.settings.features.reach_margin_mm * 1e-3
    feed = ReactionFeed(model.graph, case.teeth_radius_m, margin_m, model.threshold, case.frame_dt_s, ReamerHoldConfig())
    return step, feed


def _removed(masks, case, model) -> int:
    return int((masks[-1] & ~(case.alpha[0] < model.threshold)).sum())


def test_the_card_records_the_reamer_sizes_and_the_law_is_non_negative(socket_model, case):
    assert socket_model.trained_reamer_mm == (round(2e3 * case.teeth_radius_m, 3),)
    step, _ = _parts(socket_model, case)
    step(BoneState.start(case.alpha[0]), case.positions[3], case.axis, 230.0, 0.0, case.omega_rad_s)
    assert step.reaction_law is not None and step.reaction_law.shape == (4,)
    assert (step.reaction_law >= 0).all()


def test_no_push_no_advance_no_cut(law_model, case):
    step, feed = _parts(law_model, case)
    masks, centres = rollout(step, case, 3, 6, law_model.threshold, feed, push_n=0.0)
    assert np.allclose(centres, case.positions[3])
    assert _removed(masks, case, law_model) == 0


def test_in_free_air_the_reamer_cuts_nothing_and_stops_at_the_bone(law_model, case):
    step, feed = _parts(law_model, case)
    away = case.positions[0] - 0.1 * case.axis  # 100 mm clear of the bone
    state = BoneState.start(case.alpha[0])
    new = step(state, away, case.axis, 230.0, 1e-3, case.omega_rad_s)
    assert step.last.region == 0 and np.array_equal(new.alpha, state.alpha)
    assert step.reaction_law is not None and not step.reaction_law.any()
    free = 230.0 / ReamerHoldConfig().axial_damping_n_s_m * case.frame_dt_s  # the push against the hold alone
    assert feed.advance_m(step.reaction_law, state.alpha, away, case.axis, 230.0) == pytest.approx(free)
    contact = advance_to_support(law_model.mesh.nodes, away, case.axis, case.teeth_radius_m, 1)
    assert free < contact < 0.1
    assert feed.advance_m(step.reaction_law, state.alpha, away, case.axis, 1e6) == pytest.approx(contact)  # never past the bone


def test_closing_in_the_reamer_stops_where_the_cutting_front_holds_the_bone(socket_model, case):
    # a front reach barely past the teeth: the first node touches the teeth before any element's
    # centroid is in reach, so stopping at the touch would leave the law empty and the reamer stuck
    features = socket_model.settings.features.model_copy(update={"reach_margin_mm": 0.01})
    step = LearnedStep(socket_model.gn, socket_model.graph, features, case.teeth_radius_m, case.element_cutting_energy_j_m3)
    feed = ReactionFeed(socket_model.graph, case.teeth_radius_m, 1e-5, socket_model.threshold, case.frame_dt_s, ReamerHoldConfig())
    centre = case.positions[0] - 0.1 * case.axis
    state = BoneState.start(case.alpha[0])
    step(state, centre, case.axis, 1e6, 0.0, case.omega_rad_s)
    stop = feed.advance_m(step.reaction_law, state.alpha, centre, case.axis, 1e6)
    active = state.alpha >= socket_model.threshold
    attached = socket_model.mesh.nodes[np.unique(socket_model.mesh.tets[active])]
    assert stop > advance_to_support(attached, centre, case.axis, case.teeth_radius_m, 1)
    step(state, centre + stop * case.axis, case.axis, 1e6, stop, case.omega_rad_s)
    assert step.last.region > 0 and step.reaction_law.any()  # the front holds bone: the law, not the free air, moves it on
    assert feed.advance_m(step.reaction_law, state.alpha, centre + stop * case.axis, case.axis, 230.0, stop) > 0.0


def test_pulled_back_the_reamer_cuts_nothing(law_model, case):
    step, _ = _parts(law_model, case)
    state = BoneState.start(case.alpha[6])
    back = case.positions[6] - 0.2e-3 * case.axis
    assert np.array_equal(step(state, back, case.axis, 230.0, -0.2e-3, case.omega_rad_s).alpha, state.alpha)


def test_more_push_never_removes_less(law_model, case):
    step, feed = _parts(law_model, case)
    removed, depth = [], []
    for push in (0.0, 50.0, 150.0, 230.0, 310.0, 600.0):
        masks, centres = rollout(step, case, 2, 8, law_model.threshold, feed, push_n=push)
        removed.append(_removed(masks, case, law_model))
        depth.append(float((centres[-1] - case.positions[2]) @ case.axis))
    assert removed == sorted(removed) and depth == sorted(depth)
    assert removed[0] == 0 and removed[-1] > 0


def test_the_feed_follows_the_law():
    law = np.array([100.0, 5e4, 0.1, 10.0])
    assert feed_m_s(law, 50.0, 2000.0) == 0.0  # the bone holds more than the push: stalled
    assert feed_m_s(law, 230.0, 2000.0) == pytest.approx(130.0 / 52000.0)
    assert feed_m_s(law, 310.0, 2000.0) > feed_m_s(law, 230.0, 2000.0)


def test_in_contact_a_rising_balance_is_approached_part_way_a_falling_one_at_once(socket_model, case):
    from thrsim.learn.reaction_feed import FEED_RELAXATION

    _, feed = _parts(socket_model, case)
    law = np.array([100.0, 5e4, 0.1, 10.0])
    balanced = feed_m_s(law, 230.0, feed.damping_n_s_m) * case.frame_dt_s
    centre = case.positions[0]
    for last in (0.0, 0.5 * balanced, 1e-3, 4e-3):  # from standing, from a slow frame, from two plunging ones
        moved = feed.advance_m(law, case.alpha[0], centre, case.axis, 230.0, last)
        expected = FEED_RELAXATION * balanced + (1 - FEED_RELAXATION) * last if last < balanced else balanced
        assert moved == pytest.approx(expected)
        assert feed.advance_m(law, case.alpha[0], centre, case.axis, 0.0, last) == 0.0  # no push: no advance, whatever came before
        assert feed.advance_m(law, case.alpha[0], centre, case.axis, 310.0, last) >= moved  # more push, never less
    # seating: a soft bone until 1 mm deep, then one that holds more than the push; the reamer stops in the
    # frame it reads that law (coasting half the last advance each frame went on for 0.25 mm past the seat)
    seat_m = 1e-3
    law_at = lambda depth: np.array([50.0 if depth < seat_m else 1000.0, 1e4, 0.0, 0.0])  # noqa: E731
    depth, advance, past_seat = 0.0, 0.0, []
    for _ in range(20):
        advance = feed.advance_m(law_at(depth), case.alpha[0], centre, case.axis, 230.0, advance)
        if depth >= seat_m:
            past_seat.append(advance)
        depth += advance
    assert past_seat and all(a == 0.0 for a in past_seat)


def test_a_stall_bounds_the_law_from_below_and_a_feed_fixes_it():
    import torch

    from thrsim.learn.learned_simulator import law_errors

    law = torch.tensor([[30.0, 1e3, 0.2, 5.0]] * 4)
    # stalled at 20 N (the law holds 30: no error) and at 40 N (the law holds too little); fed at 2 mm/s
    recorded = torch.tensor([[20.0, 0.2, 0.0], [40.0, 0.2, 0.0], [32.0, 0.21, 2e-3], [30.0, 0.21, 2e-3]])
    force, torque = law_errors(law, recorded, torch.tensor([10.0, 0.1]))
    assert force.tolist() == pytest.approx([0.0, -1.0, 0.0, 0.2])
    assert torque.tolist() == pytest.approx([0.0, 0.0, 0.0, 0.0], abs=1e-6)


def test_the_feed_loss_weighs_a_reaction_error_by_the_feed_it_would_cause():
    import torch

    from thrsim.learn.learned_simulator import balanced_feed_errors, law_errors

    # seated at 230 N: the solver feeds 0.3 mm/s against a reaction of 229.4 N; damping 2,000 N·s/m
    recorded = torch.tensor([[229.4, 0.5, 3e-4, 230.0, 2000.0]] * 3)
    law = torch.tensor(
        [
            [199.4, 1e5, 0.5, 0.0],  # R(v) = A + B·v meets the record, so it balances the push at the recorded feed
            [189.4, 1e5, 0.5, 0.0],  # 10 N short, stiff: balances at 0.40 mm/s
            [217.9, 5e3, 0.5, 0.0],  # 10 N short, soft: balances at 1.7 mm/s
        ]
    )
    force, _ = law_errors(law, recorded, torch.tensor([230.0, 0.5]))
    assert force.tolist() == pytest.approx([0.0, -10.0 / 230.0, -10.0 / 230.0], abs=1e-5)  # the reaction's loss: a tie
    errors = balanced_feed_errors(law, recorded, 1e-4).tolist()
    assert abs(errors[0]) < 1e-3
    assert errors[1] == pytest.approx(math.log1p(4.0) - math.log1p(3.0), rel=0.05)
    assert errors[2] > 5 * errors[1]  # the feed's loss: the soft law would plunge
    stalled = torch.tensor([[230.0, 0.5, 0.0, 230.0, 2000.0]])
    assert float(balanced_feed_errors(torch.tensor([[240.0, 1e4, 0.5, 0.0]]), stalled, 1e-4)[0]) == 0.0  # holds the push: no feed


def test_a_wider_feed_loss_scale_fits_a_noisy_seated_feed_without_bias():
    import torch

    from thrsim.learn.learned_simulator import balanced_feed_errors

    # a seated reamer's feed over six frames scatters (0.02–0.7 mm/s, mean 0.34): the one feed a law can
    # balance at that fits them best on log(1 + v/v₀) is their mean only where v₀ is well above them
    feeds_m_s = torch.tensor([0.02e-3, 0.3e-3, 0.7e-3])
    recorded = torch.stack(
        [torch.full((3,), 229.4), torch.full((3,), 0.5), feeds_m_s, torch.full((3,), 230.0), torch.full((3,), 2000.0)], 1
    )
    candidates_m_s = torch.linspace(0.05e-3, 0.6e-3, 1101)

    def best_feed(scale_m_s: float) -> float:
        slope = 1e5
        losses = [
            balanced_feed_errors(torch.tensor([[230.0 - (slope + 2000.0) * float(v), slope, 0.5, 0.0]] * 3), recorded, scale_m_s)
            .square()
            .mean()
            for v in candidates_m_s
        ]
        return float(candidates_m_s[int(torch.stack(losses).argmin())])

    mean_m_s = float(feeds_m_s.mean())
    assert best_feed(1e-4) < 0.75 * mean_m_s  # 0.1 mm/s: 0.24 mm/s, the geometric-like mean
    assert 0.88 * mean_m_s < best_feed(1e-3) <= mean_m_s  # 1 mm/s: 0.31 mm/s


def test_a_slow_frame_is_a_stall_only_if_it_cut_nothing(case):
    from thrsim.learn.training import REACTION_FRAMES, next_reaction

    frames = case.frames
    slow = dataclasses.replace(case, positions=case.positions[:1] + 1e-5 * case.frame_dt_s * np.arange(frames)[:, None] * case.axis)
    slow.reaction_n, slow.motor_torque_n_m = np.full(frames, 200.0), np.full(frames, 1.0)
    uncut = dataclasses.replace(slow, alpha=np.ones_like(case.alpha))
    assert next_reaction(uncut, 2, 0.5) == (200.0, 1.0, 0.0)  # 10 µm/s and nothing removed: the push did not overcome the bone
    cut = uncut.alpha.copy()
    cut[2 + REACTION_FRAMES :, 0] = 0.0  # one element goes within the six frames
    reaction, torque, feed = next_reaction(dataclasses.replace(slow, alpha=cut), 2, 0.5)
    assert feed == pytest.approx(1e-5) and feed > 0.0  # a slow feed that cuts (a seated whole socket's): not a stall


def test_training_learns_the_law_from_pushed_cases_only(synthetic_dataset):
    from thrsim.learn.training import Trainer

    mesh, cases = load_cases(synthetic_dataset, splits=("train",), one_mesh=False)
    fed = dataclasses.replace(cases[0], case_id="set-feed", set_feed_mm_s=1.0)
    trainer = Trainer(StaticGraph(mesh), [fed, *cases[1:]], [], tiny_socket_settings(), 0.5)
    assert trainer.reaction_case_ids == {case.case_id for case in cases[1:]}
    assert all(math.isnan(value) for value in trainer._sample(0, None)[4])  # the set-feed case's frames teach no law


def test_the_law_can_learn_from_whole_sockets_only_with_a_share_of_each_epoch(synthetic_dataset):
    from thrsim.geometry.mesh import WINDOW_SIDE
    from thrsim.learn.training import Trainer

    mesh, cases = load_cases(synthetic_dataset, splits=("train",), one_mesh=False)
    window_mesh = dataclasses.replace(cases[0].mesh, node_sets={**cases[0].mesh.node_sets, WINDOW_SIDE: np.array([0, 1, 2])})
    window = dataclasses.replace(cases[0], case_id="window", mesh=window_mesh)
    assert window.is_window() and not cases[1].is_window()
    settings = tiny_socket_settings(law_from="whole_socket", law_case_share=0.75, max_samples_per_epoch=8)
    trainer = Trainer(StaticGraph(mesh), [window, *cases[1:]], [], settings, 0.5)
    assert trainer.reaction_case_ids == {case.case_id for case in cases[1:]}  # a pushed window teaches no law
    law_target = trainer._sample(int(np.flatnonzero(trainer.samples[:, 0] == 1)[0]), None)[4]
    assert law_target[3:] == (cases[1].recorded_push_n(), cases[1].hold.axial_damping_n_s_m)  # what the feed's loss balances
    order = trainer._epoch_order(np.random.default_rng(0))
    in_law = [trainer.train_cases[trainer.samples[i, 0]].case_id in trainer.reaction_case_ids for i in order]
    assert len(order) == 8 and sum(in_law) == 6  # three quarters of the epoch from the law's cases
    with pytest.raises(ThrsimInputError, match="whole sockets"):
        Trainer(StaticGraph(mesh), [window], [], settings, 0.5)


def test_the_feed_loss_adds_to_a_training_step_s_loss_only_when_weighted(synthetic_dataset):
    from thrsim.learn.training import Trainer

    mesh, cases = load_cases(synthetic_dataset, splits=("train",), one_mesh=False)
    losses = []
    for weight in (0.0, 1.0):
        trainer = Trainer(StaticGraph(mesh), cases, [], tiny_socket_settings(feed_loss_weight=weight), 0.5)
        inputs, alpha_next, damage_next = trainer._batch([trainer._sample(i, None) for i in range(0, len(trainer.samples), 3)])
        losses.append(trainer.gn.loss(inputs, alpha_next, damage_next).item())
    assert all(math.isfinite(loss) for loss in losses) and losses[1] > losses[0]  # same seed, same network: the feed's error added


def test_a_law_with_the_cutting_prior_starts_from_the_networks_of_one_without(tiny_socket_model, synthetic_dataset):
    from pydantic import ValidationError

    from thrsim.learn.settings import ArchSettings
    from thrsim.learn.training import Trainer

    mesh, cases = load_cases(synthetic_dataset, splits=("train",), one_mesh=False)
    init = load_model(tiny_socket_model)
    trainer = Trainer(StaticGraph(mesh), cases, [], tiny_socket_settings(reaction_prior="cutting"), 0.5)
    trainer._start_from(init)  # the same network: only the law's weights differ
    index = int(np.flatnonzero(trainer.samples[:, 1] >= 4)[0])
    prior_inputs, _, _ = trainer._batch([trainer._sample(index, None)])
    plain = Trainer(StaticGraph(mesh), cases, [], tiny_socket_settings(), 0.5)
    plain_inputs, _, _ = plain._batch([plain._sample(index, None)])
    with torch.no_grad():
        law = trainer.gn.reaction_law(prior_inputs, trainer.gn.outputs(prior_inputs).reaction)
        before = init.gn.reaction_law(plain_inputs, init.gn.outputs(plain_inputs).reaction)
    assert torch.allclose(law[:, [0, 2]], before[:, [0, 2]])  # at no feed the same law
    assert not torch.allclose(law[:, [1, 3]], before[:, [1, 3]])  # per unit of feed, what cutting costs
    with pytest.raises(ValidationError, match="reaction_head"):
        ArchSettings(reaction_prior="cutting")


def test_the_overshoot_constraint_moves_seated_reamers_deeper_and_asks_the_law_for_the_push(synthetic_dataset):
    from thrsim.learn.training import Trainer

    mesh, cases = load_cases(synthetic_dataset, splits=("train",), one_mesh=False)
    trainer = Trainer(StaticGraph(mesh), cases, [], tiny_socket_settings(overshoot_loss_weight=1.0, overshoot_mm=(0.5, 0.5)), 0.5)
    rng = np.random.default_rng(0)
    drawn = [(i, trainer._overshoot_sample(i, rng)) for i in range(len(trainer.samples))]
    seated = [(i, d) for i, d in drawn if d is not None]
    assert seated and len(seated) < len(drawn)  # the approach (a reaction under half the push) is left out
    index, ((sub, _, (nodes, _, _)), _, target, _) = seated[0]
    case = trainer.train_cases[trainer.samples[index, 0]]
    assert target[0] == target[3] == case.recorded_push_n() and target[2] == 0.0  # the push, met at no feed
    plain_sub, _, (plain, _, _) = trainer._sample(index, None)[0]
    assert sub.n_region >= plain_sub.n_region  # deeper, the teeth reach at least as much bone
    assert nodes.shape != plain.shape or not np.allclose(nodes, plain)  # the nodes' features, relative to the teeth, moved
    overshoot = trainer._overshoot_batch(np.arange(len(trainer.samples)), rng)
    assert overshoot is not None
    loss = trainer.gn.overshoot_loss(overshoot)
    law = trainer.gn.reaction_law(overshoot, trainer.gn.outputs(overshoot).reaction)
    expected = (torch.clamp(overshoot.reaction[:, 3] - law[:, 0], min=0.0) / trainer.gn.reaction_scale[0]).square().mean()
    assert math.isfinite(loss.item()) and loss.item() == pytest.approx(expected.item())
    assert (overshoot.reaction[:, 3] > law[:, 0]).any() and loss.item() > 0.0  # an untrained law falls short of the push
    loss.backward()  # it trains the reaction head
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in trainer.gn.parameters())


def test_evaluate_scores_a_socket_model_by_reamer_size_with_its_reaction(socket_model, synthetic_dataset):
    from thrsim.learn.evaluation import bone_key, evaluate

    _, cases = load_cases(synthetic_dataset, splits=("test",), one_mesh=False)
    report = evaluate(socket_model, cases, start_stride=6, one_step_stride=6)
    size = f"{2e3 * cases[0].teeth_radius_m:g}"
    assert report["rows"] == "reamer_diameter_mm"
    for source in (report, report["tool_forced"], report["mlp"], report["geometric"]):
        assert source[size]["1"]["windows"] > 0
    assert set(report["by_layer"]["tool_forced"]) == {"cortical"}  # the synthetic block: one material
    assert set(report["by_control"]["autonomous"]) == {"pushed"}  # the synthetic cases: a set push, no set feed
    assert report["by_control"]["autonomous"]["pushed"]["end"]["windows"] > 0
    assert report["geometric"][size]["longest_horizon"]["cavity_depth_error_mean_mm"] >= 0.0
    assert "cavity_diameter_error_mean_mm" in report["geometric"][size]["longest_horizon"]
    checks = report["physics_checks"]
    assert checks["checked"] and checks["held"] == dict.fromkeys(
        ("no_push_no_cut", "no_push_no_advance", "more_push_never_less"), len(cases)
    )
    errors = report["reaction"][size]
    assert 0.0 <= errors["force_error"] < 10.0 and 0.0 <= errors["torque_error"] < 10.0
    # every test case was pushed: what the simulator reports under the push, against the solver's reaction
    assert errors["pushed_cases"] == len(cases)
    for name in ("felt_force_error", "felt_torque_error", "felt_force_step_mean_error", "felt_torque_step_mean_error"):
        assert 0.0 <= errors[name] < 10.0
    assert 0.0 <= errors["balanced_feed_share"] < 100.0 and 0.0 <= errors["seated_balanced_feed_share"] < 100.0
    # the same cases by bone: one row per bone the cases ream, every case in one of them
    by_bone = report["reaction_by_bone"]
    assert set(by_bone) == {bone_key(case) for case in cases}
    assert sum(row["pushed_cases"] for row in by_bone.values()) == len(cases)


def test_the_reaction_report_weighs_frames_and_steps_apart():
    from thrsim.learn.evaluation import reaction_report

    # a pushed case 10 N over and 10 N under in its two frames of 100 N: 10 % a frame, none in the step's mean;
    # a set-feed case counts in the law's error only
    pushed = {
        "law": np.array([20.0, 200.0, 2.0, 4.0]),
        "felt": np.array([20.0, 200.0, 1.0, 4.0]),
        "felt_step": np.array([0.0, 200.0, -1.0, 4.0]),
        "feed": np.array([0.6e-3, 0.8e-3, 0.1e-3, 0.2e-3]),  # the law balances the push at 3/4 of the solver's feed, half seated
    }
    set_feed = {"law": np.array([60.0, 200.0, 0.0, 4.0])}
    row = reaction_report({"48": [pushed, set_feed]})["48"]
    assert row["force_error"] == pytest.approx(0.2) and row["torque_error"] == pytest.approx(0.25) and row["pushed_cases"] == 1
    assert row["felt_force_error"] == pytest.approx(0.1) and row["felt_force_step_mean_error"] == 0.0
    assert row["felt_torque_error"] == pytest.approx(0.25) and row["felt_torque_step_mean_error"] == pytest.approx(0.25)
    assert row["balanced_feed_share"] == pytest.approx(0.75) and row["seated_balanced_feed_share"] == pytest.approx(0.5)
    assert "felt_force_error" not in reaction_report({"48": [set_feed]})["48"]


def test_the_simulator_reams_any_bone_with_any_size_and_reports_the_reaction(socket_model, case):
    from thrsim.data.synthetic import block_mesh
    from thrsim.learn.simulator import ReamingSimulator

    bone = block_mesh(n=5)  # not the mesh the model was trained on
    simulator = ReamingSimulator(model=socket_model, mesh=bone)
    assert simulator.n_elements == bone.n_tets
    trained = socket_model.trained_reamer_mm[0]
    still = [simulator.step(case.axis, 0.0, reamer_mm=trained) for _ in range(3)]
    assert all(result.advance_m == 0.0 and not result.removed.any() for result in still)
    pushed = [simulator.step(case.axis, 230.0, reamer_mm=trained) for _ in range(8)]
    assert all(result.advance_m >= 0.0 for result in pushed) and sum(result.advance_m for result in pushed) > 0
    assert all(result.reaction_n is not None and result.reaction_n >= 0.0 for result in pushed)
    assert all(result.motor_torque_n_m is not None and result.motor_torque_n_m >= 0.0 for result in pushed)
    assert "push" not in pushed[-1].out_of_range and set(pushed[-1].out_of_range) <= {"feed", "tilt"}  # it reads the feed
    fastest = socket_model.trained_feed_mm_s[1]
    lunge = pushed[-1].reamer_position + 2e-3 * fastest * socket_model.frame_dt_s * np.asarray(case.axis)  # twice the fastest
    assert "feed" in simulator.step(case.axis, 230.0, reamer_position=lunge, reamer_mm=trained).out_of_range
    sideways = np.cross(case.axis, (1.0, 0.0, 0.0) if abs(case.axis[0]) < 0.9 else (0.0, 1.0, 0.0))
    aside = pushed[-1].reamer_position + 3e-3 * sideways / np.linalg.norm(sideways)  # its axis 3 mm off the centre
    assert "centre" in simulator.step(case.axis, 230.0, reamer_position=aside, reamer_mm=trained).out_of_range
    bigger = simulator.step(case.axis, 230.0, reamer_mm=trained + 4.0)
    assert bigger.reamer_mm == trained + 4.0 and "reamer size" in bigger.out_of_range
    tilted = simulator.step((0.0, np.sin(np.radians(80.0)), -np.cos(np.radians(80.0))), 230.0, reamer_mm=trained)
    assert "tilt" in tilted.out_of_range  # the synthetic cases tilt 0-30°
    with pytest.raises(ThrsimInputError):
        ReamingSimulator(model=socket_model, mesh=bone, cancellous="chalk")


def test_a_law_summed_over_more_contact_than_it_learned_is_flagged(socket_model, case):
    import copy

    from thrsim.learn.simulator import ReamingSimulator

    low, high = socket_model.trained_law_contact_mm2  # the trainer recorded the contact of the frames the law learned from
    assert 0.0 < low <= high

    def replay(model):
        simulator = ReamingSimulator(model=model)
        size = model.trained_reamer_mm[0]
        return [simulator.step(case.axis, 230.0, reamer_position=p, reamer_mm=size) for p in case.positions[:8]]

    results = replay(socket_model)
    contacts = [r.law_contact_mm2 for r in results[1:]]  # each frame's law was read on the frame before
    assert results[0].law_contact_mm2 is None and all(c is not None for c in contacts) and max(contacts) > 0.0
    assert all(("contact" in r.out_of_range) == (r.law_contact_mm2 > high) for r in results[1:])
    # a law that learned on half the largest contact here: the frames beyond it are flagged, the others not
    card = copy.deepcopy(socket_model.card)
    card["data"]["law_contact_mm2"] = [0.0, 0.5 * max(contacts)]
    narrow = replay(dataclasses.replace(socket_model, card=card))
    assert [r.law_contact_mm2 for r in narrow[1:]] == contacts
    assert [("contact" in r.out_of_range) for r in narrow[1:]] == [c > 0.5 * max(contacts) for c in contacts]
    assert any("contact" in r.out_of_range for r in narrow)
    del card["data"]["law_contact_mm2"]  # a card written before cards recorded it: nothing to flag against
    assert not any("contact" in r.out_of_range for r in replay(dataclasses.replace(socket_model, card=card)))


def test_a_socket_reamed_into_the_medial_wall_ends_as_the_solver_ends_it():
    from thrsim.config import SocketConfig
    from thrsim.geometry.mesh import MEDIAL_WALL
    from thrsim.geometry.reaming_path import breach_faces
    from thrsim.geometry.socket import generate_socket
    from thrsim.learn.bench import untrained_model
    from thrsim.learn.settings import preset
    from thrsim.learn.simulator import MEDIAL_WALL_BREACHED, ReamingSimulator

    mesh = generate_socket(SocketConfig(element_size_mm=2.5))
    model = untrained_model(mesh, preset("socket"), teeth_radius_m=24e-3)
    model.card["reamer"]["sizes_mm"] = [48.0]
    simulator = ReamingSimulator(model=model, mesh=mesh)
    axis = np.array([0.0, 0.0, -1.0])
    assert simulator.step(axis, 230.0, reamer_mm=48.0).end_reason is None
    on_wall = breach_faces(mesh)[MEDIAL_WALL]
    assert len(on_wall) > 0
    simulator.bone.alpha[on_wall[:1]] = 0.0  # one element of the medial wall's pelvic face gone
    assert simulator.step(axis, 230.0, reamer_mm=48.0).end_reason == MEDIAL_WALL_BREACHED


def test_thrsim_ream_reams_the_whole_socket_with_a_sequence_of_reamers(socket_model, tmp_path):
    import json

    from learn_helpers import run_thrsim

    size = socket_model.trained_reamer_mm[0]
    reamers = f"{size:g},{size + 2:g}"
    done = run_thrsim(
        "ream", "--bone", "socket", "--model", str(socket_model.path), "--reamers", reamers, "--element-size", "2.5",
        "--frames", "6", "--out", str(tmp_path / "socket"), "--json", timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert [step["reamer_mm"] for step in summary["reamers"]] == [size, size + 2]
    assert all(step["frames"] >= 1 and step["ended"] in ("seated", "frames", "passed_through") for step in summary["reamers"])
    assert "reamer size" in summary["reamers"][1]["out_of_range"]  # the synthetic cases had one size
    assert (tmp_path / "socket" / "ream.pvd").is_file()
    for bad, says in (
        (("--reamers", f"{size + 2:g},{size:g}"), "growing"),
        (("--reamers", "4x"), "numbers"),
        (("--element-size", "0.01"), "[0.3, 5]"),
    ):
        refused = run_thrsim("ream", "--bone", "socket", "--model", str(socket_model.path), *bad, "--out", str(tmp_path / "bad"))
        assert refused.returncode == 2 and says in refused.stderr and len(refused.stderr.strip().splitlines()) == 1
        assert not (tmp_path / "bad").exists()
    from thrsim.learn.model_dir import SHIPPED_MODEL

    patch = run_thrsim("ream", "--bone", "socket", "--model", str(SHIPPED_MODEL), "--out", str(tmp_path / "patch"))  # a patch model
    assert patch.returncode == 2 and "socket feature set" in patch.stderr


def test_the_reaction_law_follows_the_area_in_contact_not_the_element_count():
    import torch

    from thrsim.data.synthetic import block_mesh
    from thrsim.learn.bench import untrained_model
    from thrsim.learn.settings import preset

    laws, regions = [], []
    for n in (4, 8):  # the same block, elements of half the size
        mesh = block_mesh(n=n)
        model = untrained_model(mesh, preset("socket"), teeth_radius_m=3e-3)
        with torch.no_grad():  # every node the same share of reaction
            model.gn.network.output.weight.zero_()
            model.gn.network.output.bias.fill_(1.0)
        step = LearnedStep(model.gn, model.graph, model.settings.features, 3e-3, np.full(mesh.n_tets, 5e8))
        axis = np.array([0.0, 0.0, -1.0])
        step(BoneState.start(np.full(mesh.n_tets, 0.58, dtype=np.float32)), np.array([0.0, 0.0, -22e-3 + 2.5e-3]), axis, 230.0, 0.0, 136.0)
        laws.append(step.reaction_law[0])
        regions.append(step.last.region)
    assert regions[1] > 3 * regions[0]  # many more elements in contact on the finer mesh
    assert 0.5 < laws[1] / laws[0] < 2.0  # about the same reaction
