"""The reaming assessment is the session's record, not the final bone: a perforation undone or
restored still counts and scores; criteria never contradict one another; a push outside the range
the model learned is an event; a session with nothing done is not scored; a hidden page holds reaming."""

from __future__ import annotations

import json

import numpy as np
import pytest
from checkout_cli import run_main

from thrsim.app.controls import parse_reaming_control
from thrsim.app.live import LiveSession
from thrsim.app.modes import MODES
from thrsim.app.reaming import ReamingTrainer
from thrsim.config import BonePatchConfig
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.learn.simulator import ReamingSimulator
from thrsim.report import build_assessment, build_report
from thrsim.report.reaming import criteria, metrics
from thrsim.session.reaming import ReamingRecord

STEP = 1 / 60


class Clock:
    """A live session on a clock the test moves."""

    def __init__(self, folder, **settings):
        self.now = 0.0
        self.session = LiveSession(MODES["reaming"], {"side": "right", "seed": 1, **settings}, lambda: self.now, folder)

    def control(self, **message) -> str:
        return self.session.control(json.dumps(message))[1]

    def run(self, seconds: float) -> dict:
        for _ in range(int(round(seconds / STEP))):
            self.now += STEP
            state = self.session.tick()
        return state


def _points(assessment) -> dict[str, float]:
    return {c.name: c.points for c in assessment.criteria}


def test_a_perforation_undone_and_restored_still_counts_and_scores(tmp_path, monkeypatch, capsys):
    clock = Clock(tmp_path)
    clock.control(type="reamer", inclination_deg=55, anteversion_deg=15)  # 15° off the axis: through in 60–150 frames
    clock.control(type="run", action="start")
    clock.run(3.0)
    started, through = (e["kind"] for e in clock.session.trainer.events)  # through the 2 mm patch: with bone left around or none
    assert started == "start" and through in ("perforated", "passed_through")
    assert clock.control(type="run", action="undo").startswith("undid")
    clock.control(type="run", action="reset")  # R: the intact bone again
    assert clock.session.trainer.simulator.removed.sum() == 0
    clock.control(type="run", action="start")
    clock.run(0.3)  # careful reaming of the restored bone
    path = clock.session.save()

    assessment = build_assessment(path)
    points = _points(assessment)
    kinds = [e["kind"] for e in assessment.events]
    assert kinds[:4] == ["start", through, "undo", "restore"] and all({"kind", "time_s"} <= set(e) for e in assessment.events)
    perforation = next(c for c in assessment.criteria if c.name == "no perforation or breach")
    assert perforation.points == 0 and perforation.measured.startswith("perforated") and "undone" in perforation.measured
    assert points["cavity prepared"] == 0 and points["over-reaming"] == 0  # a cavity reamed through is not one prepared to plan
    assert points["no undo or restore"] == 0  # one undo and one restore
    assert assessment.metrics["perforations"] == 1 and assessment.metrics["undos"] == 1 and assessment.metrics["restores"] == 1
    assert assessment.score < assessment.max_score - 4
    # the command prints the same assessment as one JSON object
    code, out, _ = run_main(monkeypatch, capsys, "report", str(path), "--json")
    printed = json.loads(out)
    assert code == 0 and set(printed) == {"score", "max_score", "criteria", "events", "metrics"}
    assert printed["score"] == assessment.score and printed["metrics"]["perforations"] == 1
    assert set(printed["criteria"][0]) == {"name", "measured", "rule", "points", "max_points"}
    assert "Reaming: errors and corrections" in build_report(path)


def _record(removed: np.ndarray, events: list[dict], frames: int = 30) -> ReamingRecord:
    """A reaming record whose final bone is ``removed`` and whose session held ``events``."""
    mesh = generate_bone_patch(BonePatchConfig(element_size_mm=0.45))
    geometry = {
        "centroids_m": mesh.centroids,
        "outer": np.isin(mesh.tets, mesh.node_sets["outer"]).sum(axis=1) >= 3,
        "inner_radius_m": 0.022,
        "outer_radius_m": 0.024,
        "teeth_radius_m": 0.0229,
        "threshold": 0.3,
    }
    frame = np.arange(1, frames + 1)
    position = np.zeros((frames, 3))
    position[:, 2] = -frame * 0.1e-3
    return ReamingRecord(
        "right", {}, "", np.eye(4), frame / 60, frame, np.full(frames, 230.0), np.tile([0, 0, -1.0], (frames, 1)), position,
        frame * 10, frame * 1.0, frame * 0.1, np.zeros((frames, 3)), events, (150.0, 310.0),
        np.where(removed, 0.0, 0.8).astype(np.float32), 0, ReamingTrainer().navigation.record(), geometry,
    )  # fmt: skip


@pytest.fixture(scope="module")
def on_plan() -> np.ndarray:
    centroids = generate_bone_patch(BonePatchConfig(element_size_mm=0.45)).centroids
    return np.linalg.norm(centroids, axis=1) < 0.0229


def test_criteria_never_contradict_a_perforation(on_plan):
    clean = {c.name: c for c in criteria(_record(on_plan, [{"time_s": 0.0, "kind": "start", "detail": "", "frame": 0}]))}
    assert clean["no perforation or breach"].points == 2 and clean["cavity prepared"].points == 1 and clean["over-reaming"].points == 1
    perforated = {"time_s": 0.4, "kind": "perforated", "detail": "", "frame": 24}
    undone = {"time_s": 0.5, "kind": "undo", "detail": "60 frames", "frame": 0, "frames": 24}
    record = _record(on_plan, [perforated, undone])  # the same final bone: the perforation was undone
    found = {c.name: c for c in criteria(record)}
    assert (
        found["no perforation or breach"].points == 0 and "perforated at 0.4 s, then undone" in found["no perforation or breach"].measured
    )
    for name in ("cavity prepared", "over-reaming"):  # no green cavity beside a perforation
        assert found[name].points == 0 and "perforated" in found[name].measured
    assert found["no undo or restore"].points == 0.5
    # the socket model's errors score alike (the patch reports none of them today)
    breached = {c.name: c.points for c in criteria(_record(on_plan, [{**perforated, "kind": "medial_wall_breached"}]))}
    assert breached["no perforation or breach"] == 0 and breached["cavity prepared"] == 0


def test_metrics_count_events_and_measure_push_and_path(on_plan):
    events = [
        {"time_s": 0.1, "kind": "push_out_of_range", "detail": "", "frame": 6, "force_n": 350.0},
        {"time_s": 0.2, "kind": "undo", "detail": "", "frame": 0, "frames": 12},
    ]
    record = _record(on_plan, events)
    record.force_n[:10] = 350.0
    record.frame[20:] -= 12  # frames after the undo start again from frame 8
    found = metrics(record)
    assert found["undos"] == 1 and found["restores"] == 0 and found["perforations"] == 0
    assert found["push_mean_n"] == pytest.approx((10 * 350 + 20 * 230) / 30)
    assert found["push_out_of_range_fraction"] == pytest.approx(10 / 30)
    assert found["reamer_path_length_mm"] == pytest.approx(28 * 0.1)  # the jump back at the undo is no travel
    record.trained_force_n = None  # a model card that does not say what push it learned: no figure is invented
    assert "push_out_of_range_fraction" not in metrics(record) and "push force" not in {c.name for c in criteria(record)}


@pytest.fixture(scope="module")
def shipped_simulator():
    return ReamingSimulator(threads=1)


def test_a_push_outside_the_model_cards_range_is_an_event(shipped_simulator):
    shipped_simulator.reset()
    trainer = ReamingTrainer(simulator=shipped_simulator)
    low, high = shipped_simulator.model.trained_force_n
    trainer.apply_control(parse_reaming_control({"type": "force", "newton": high + 40}), 0.0)
    trainer.apply_control(parse_reaming_control({"type": "run", "action": "start"}), 0.0)
    for k in range(1, 13):
        if k == 6:
            trainer.apply_control(parse_reaming_control({"type": "force", "newton": (low + high) / 2}), k * STEP)
        if k == 9:
            trainer.apply_control(parse_reaming_control({"type": "force", "newton": low - 40}), k * STEP)
        trainer.step(k * STEP)
    pushes = [e for e in trainer.events if e["kind"] == "push_out_of_range"]
    assert [e["force_n"] for e in pushes] == [high + 40, low - 40]  # once per stretch outside the range
    assert pushes[0]["trained_force_n"] == [low, high] and f"{low:g}–{high:g} N" in pushes[0]["detail"]


def test_a_session_with_nothing_done_is_not_scored(tmp_path, monkeypatch, capsys):
    clock = Clock(tmp_path)
    clock.control(type="force", newton=250)
    clock.run(0.2)
    path = clock.session.save()
    assessment = build_assessment(path)
    assert assessment.score is None and assessment.max_score is None and assessment.criteria == []
    assert "not scored" in build_report(path)
    code, out, _ = run_main(monkeypatch, capsys, "report", str(path), "--json")
    assert code == 0 and json.loads(out)["score"] is None


def test_a_hidden_page_holds_reaming_and_showing_it_goes_on(tmp_path):
    clock = Clock(tmp_path)
    clock.control(type="run", action="start")
    frames = clock.run(0.5)["reaming"]["frame"]
    assert clock.control(type="page", visible=False).startswith("page hidden")
    state = clock.run(1.0)
    assert state["reaming"]["frame"] == frames and state["reaming"]["paused"] == "page hidden" and state["reaming"]["running"]
    clock.control(type="page", visible=True)
    state = clock.run(0.5)
    assert state["reaming"]["paused"] is None and state["reaming"]["behind_frames"] == 0
    assert abs(state["reaming"]["frame"] - (frames + 30)) <= 1  # goes on from where it held, no burst for the hidden second
    kinds = [e["kind"] for e in clock.session.trainer.events]
    assert kinds == ["start", "page_hidden", "page_shown"]
