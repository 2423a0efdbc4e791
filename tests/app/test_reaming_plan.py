"""The plan and the reamer sequence: each measurement against the plan on a record built by hand,
the criteria scored against the thresholds file, the plan and reamer controls of the trainer (with
the shipped model), the instructor's case and thresholds files, and the session file round trip."""

from __future__ import annotations

import json
import urllib.request

import numpy as np
import pytest
from app_helpers import ServedTrainer, next_of_type, wait_for
from checkout_cli import run_main
from websockets.sync.client import connect

from thrsim.app.controls import parse_reaming_control
from thrsim.app.live import LiveSession
from thrsim.app.modes import MODES
from thrsim.app.reaming import ReamingTrainer
from thrsim.app.replay import replay_session
from thrsim.app.server import ServeSettings
from thrsim.config import SafeZone
from thrsim.errors import ThrsimInputError
from thrsim.learn.simulator import ReamingSimulator
from thrsim.nav.anatomy import local_axis_from_angles
from thrsim.nav.bone_frame import patch_in_app, reamer_axis_from_cup
from thrsim.report import build_assessment, build_report
from thrsim.report.reaming import _against_plan, criteria
from thrsim.report.reaming_metrics import final_rows, metrics
from thrsim.report.thresholds import default_thresholds, load_thresholds
from thrsim.session.plan import Plan, load_plan
from thrsim.session.reaming import ReamingRecord

DT = 1 / 60
PLAN = Plan(cup_diameter_mm=48, medialisation_mm=2, superior_shift_mm=0, inclination_deg=40, anteversion_deg=15)


def _record(frame, volume, *, angles=(45.0, 20.0), reamer=None, cut=None, positions=None, depth=None, plan=PLAN) -> ReamingRecord:
    """A reaming record of the given trace (frames, cumulative removed volume in mm³); the reamer aimed at ``angles`` (cup, radiographic)."""
    frame = np.asarray(frame, dtype=np.int64)
    n = len(frame)
    axis = reamer_axis_from_cup(local_axis_from_angles(*angles))
    return ReamingRecord(
        side="right", zone={}, mesh_digest="", patch_to_model=np.eye(4), time=np.arange(n) * DT, frame=frame,
        force_n=np.full(n, 230.0), axis=np.tile(axis, (n, 1)), position_m=np.zeros((n, 3)) if positions is None else np.asarray(positions),
        removed=np.zeros(n, dtype=np.int64), removed_volume_mm3=np.asarray(volume, dtype=float),
        depth_mm=np.arange(n) * 0.01 if depth is None else np.asarray(depth, dtype=float),
        angles=np.tile([*angles, 0.0], (n, 1)), events=[], trained_force_n=(150.0, 310.0), final_alpha=np.zeros(0, dtype=np.float32),
        behind_frames=0, navigation=ReamingTrainer().navigation.record(), cavity={}, frame_dt_s=DT,
        reamer_mm=None if reamer is None else np.asarray(reamer, dtype=float), cut_mm=None if cut is None else np.asarray(cut, dtype=float),
        plan=None if plan is None else plan.model_dump(),
    )  # fmt: skip


def test_the_final_bone_keeps_only_the_frames_no_undo_or_restore_went_back_over():
    # frames 1-5, undo back to 2, frames 3-4, restore, frames 1-2
    frame = [1, 2, 3, 4, 5, 3, 4, 1, 2]
    assert final_rows(_record(frame, np.arange(9.0))).tolist() == [7, 8]
    assert final_rows(_record([1, 2, 3, 4, 5, 3, 4], np.arange(7.0))).tolist() == [0, 1, 5, 6]


def test_an_undo_or_restore_with_nothing_reamed_after_it_still_drops_the_frames_it_went_back_over():
    record = _record([1, 2, 3, 4, 5], np.arange(5.0))
    record.events.append({"time_s": 10.0, "kind": "undo", "detail": "3 frames", "frame": 2, "frames": 3})
    assert final_rows(record).tolist() == [0, 1]
    record.events.append({"time_s": 11.0, "kind": "restore", "detail": "", "frame": 0, "frames": 2})
    assert final_rows(record).tolist() == []
    # an undo between frames: the rows before it go back, the ones after it stay
    record = _record([1, 2, 3, 4, 5, 3, 4], np.arange(7.0))
    record.events.append({"time_s": float(record.time[5]), "kind": "undo", "detail": "3 frames", "frame": 2, "frames": 3})
    assert final_rows(record).tolist() == [0, 1, 5, 6]


def test_orientation_error_is_the_cavity_axis_against_the_plan():
    found = metrics(_record(range(1, 11), np.arange(1.0, 11.0), angles=(45.0, 20.0)))
    assert found["inclination_error_deg"] == pytest.approx(5.0, abs=1e-9)
    assert found["anteversion_error_deg"] == pytest.approx(5.0, abs=1e-9)
    # the axis is weighted by the bone each kept frame removed: 9 mm³ at (42°, 13°) outweighs 1 mm³ at (60°, 30°)
    record = _record(range(1, 11), [1.0, *np.arange(2.0, 11.0)], angles=(42.0, 13.0))
    record.axis[0] = reamer_axis_from_cup(local_axis_from_angles(60.0, 30.0))
    record.removed_volume_mm3[0] = 0.0  # the first frame removed nothing: no weight
    found = metrics(record)
    assert found["inclination_error_deg"] == pytest.approx(2.0, abs=1e-9) and found["anteversion_error_deg"] == pytest.approx(2.0, abs=1e-9)
    assert metrics(_record(range(1, 4), np.zeros(3)))["inclination_error_deg"] is None  # no bone removed: no cavity axis


def test_time_within_5_and_10_degrees_of_the_plan_counts_both_angles_over_every_frame():
    record = _record(range(1, 11), np.arange(1.0, 11.0))
    record.angles[:4, :2] = (41.0, 16.0)  # within 5°
    record.angles[4:7, :2] = (47.0, 20.0)  # within 10°, not 5°
    record.angles[7:, :2] = (55.0, 15.0)  # inclination 15° off
    record.angles[9] = np.nan  # the reamer not measured: not counted
    found = metrics(record)
    assert found["within_5deg_fraction"] == pytest.approx(4 / 9) and found["within_10deg_fraction"] == pytest.approx(7 / 9)


def test_cavity_diameter_is_the_largest_reamer_the_final_bone_kept_cutting():
    cut = [44.0] * 5 + [46.0] * 5
    found = metrics(_record(range(1, 11), np.arange(1.0, 11.0), reamer=cut, cut=cut))
    assert found["cavity_diameter_mm"] == 46.0 and found["cavity_diameter_error_mm"] == pytest.approx(-2.0)
    # frames 6 and 7 with 46 mm undone, frame 6 reamed again with 44 mm: the cavity is the 44 mm reamer's
    undone = _record(
        [1, 2, 3, 4, 5, 6, 7, 6], [1, 2, 3, 4, 5, 6, 7, 6.0], reamer=[44] * 5 + [46] * 2 + [44], cut=[44] * 5 + [46] * 2 + [44]
    )
    assert metrics(undone)["cavity_diameter_mm"] == 44.0
    # a 46 mm reamer that touched no bone did not cut the cavity
    idle = _record(range(1, 7), [1, 2, 3, 3, 3, 3.0], reamer=[44] * 3 + [46] * 3, cut=[44] * 3 + [46] * 3)
    assert metrics(idle)["cavity_diameter_mm"] == 44.0


def test_medialisation_and_superior_shift_are_the_cavity_centres_from_the_native_centre():
    axes = patch_in_app(SafeZone())
    deep = axes.T @ np.array([-0.003, 0.0005, -0.0015])  # 3 mm medial, 1.5 mm superior (APP: lateral, anterior, inferior)
    shallow = axes.T @ np.array([-0.001, 0.0, 0.0])
    positions = [shallow, shallow, deep, shallow]
    found = metrics(_record(range(1, 5), [1, 2, 3, 4.0], positions=positions, depth=[0.1, 0.2, 0.5, 0.3]))
    assert found["medialisation_mm"] == pytest.approx(3.0) and found["superior_shift_mm"] == pytest.approx(1.5)
    # the centre is the largest reamer's: a deeper frame of a smaller reamer does not count
    found = metrics(_record(range(1, 5), [1, 2, 3, 4.0], positions=positions, depth=[0.1, 0.2, 0.5, 0.3], cut=[44, 44, 44, 46]))
    assert found["medialisation_mm"] == pytest.approx(1.0) and found["superior_shift_mm"] == pytest.approx(0.0, abs=1e-12)


def test_the_sequence_lists_each_reamer_that_reamed_with_its_time():
    reamer = [44.0] * 6 + [46.0] * 12 + [48.0] * 3
    found = metrics(_record(range(1, 22), np.arange(1.0, 22.0), reamer=reamer, cut=[45.8] * 21))
    assert found["reamer_sequence_mm"] == [44.0, 46.0, 48.0]
    assert found["time_per_reamer_s"] == pytest.approx([6 * DT, 12 * DT, 3 * DT])
    # the model cut 45.8 mm whatever was held: the cavity is what it cut
    assert found["cavity_diameter_mm"] == 45.8 and found["cavity_diameter_error_mm"] == pytest.approx(-2.2)


def test_the_plan_metric_and_the_keys_a_file_before_the_plan_lacks():
    found = metrics(_record(range(1, 4), [1, 2, 3.0], reamer=[44] * 3, cut=[44] * 3))
    assert found["plan"] == {
        "cup_diameter_mm": 48.0,
        "centre": {"medialisation_mm": 2.0, "superior_shift_mm": 0.0},
        "inclination_deg": 40.0,
        "anteversion_deg": 15.0,
        "source": "trainee",
    }
    assert found["medial_wall_remaining_mm"] is None  # the bone patch has no medial wall
    older = metrics(_record(range(1, 4), [1, 2, 3.0], plan=None))
    for key in ("plan", "inclination_error_deg", "within_10deg_fraction", "cavity_diameter_error_mm", "reamer_sequence_mm"):
        assert key not in older
    assert older["perforations"] == 0 and older["push_mean_n"] == 230.0


def test_the_confirmed_cup_and_the_cavity_are_measured_against_the_plan():
    """A hand-built final bone around a 46 mm plan at the native centre, axis +z (the patch frame's
    at the zone's centre): its floor, the bone removed beyond the plan and the bone left inside it,
    at the elements' centres; the last confirmed cup against the plan's angles."""
    plan = Plan(cup_diameter_mm=46, inclination_deg=40, anteversion_deg=15)
    centroids = np.array([
        [0.0, 0.0, -0.0235],  # removed, 0.5 mm beyond the planned floor (23 mm)
        [0.012, 0.0, -0.019],  # removed, inside the plan
        [0.0, 0.010, -0.019],  # kept inside the plan: sqrt(461) mm from its centre
        [0.0, 0.0, -0.0245],  # kept, beyond the plan
        [0.0, 0.0, 0.010],  # kept, inside the sphere but above the cup's rim: not the cup's bone
    ])  # fmt: skip
    record = _record([1, 2, 3, 2], [1, 2, 3, 2.0], plan=plan)
    record.cavity = {"centroids_m": centroids, "outer": np.zeros(5, dtype=bool), "inner_radius_m": 0.022, "outer_radius_m": 0.024,
                     "teeth_radius_m": 0.0229, "threshold": 0.5}  # fmt: skip
    record.final_alpha = np.array([0.0, 0.1, 1.0, 1.0, 1.0], dtype=np.float32)
    record.events = [
        {"time_s": 1.0, "kind": "cup_confirmed", "detail": "", "frame": 2, "inclination_deg": 50.0, "anteversion_deg": 30.0},
        {"time_s": 2.0, "kind": "cup_confirmed", "detail": "", "frame": 2, "inclination_deg": 43.0, "anteversion_deg": 11.0},
    ]
    found = metrics(record)
    assert found["confirmed_inclination_error_deg"] == pytest.approx(3.0) and found["confirmed_anteversion_error_deg"] == pytest.approx(4.0)
    assert found["cavity_depth_error_mm"] == pytest.approx(0.5)
    assert found["over_reaming_mm"] == pytest.approx(0.5)
    assert found["under_reaming_mm"] == pytest.approx(23.0 - np.sqrt(461.0))
    assert found["medial_wall_remaining_mm"] is None  # the patch: no medial wall, no number
    body = _against_plan(record).body
    for row in ("43.0°</td><td>3.0°", "11.0°</td><td>4.0°", "<td>0.5 mm</td>", f"<td>{23.0 - np.sqrt(461.0):.1f} mm</td>"):
        assert row in body
    assert "not modelled (the bone patch has no medial wall)" in body
    # a bone with a medial wall: the least bone left over the final bone's frames (the undone frame 3 is not the bone's)
    record.medial_wall_mm = np.array([3.0, 2.0, 0.5, 1.5])
    assert metrics(record)["medial_wall_remaining_mm"] == pytest.approx(1.5)
    assert "<td>1.5 mm</td>" in _against_plan(record).body
    # nothing confirmed, nothing removed: said, not invented
    record.events, record.final_alpha = [], np.ones(5, dtype=np.float32)
    found = metrics(record)
    assert found["confirmed_inclination_error_deg"] is None and found["cavity_depth_error_mm"] is None and found["over_reaming_mm"] is None
    assert "No cup orientation was confirmed" in _against_plan(record).body


def test_plan_criteria_score_against_the_thresholds_file(tmp_path):
    reamer = [44.0] * 6 + [46.0] * 6 + [47.0] * 6
    record = _record(range(1, 19), np.arange(1.0, 19.0), angles=(43.0, 18.0), reamer=reamer, cut=reamer)
    found = {c.name: c for c in criteria(record)}
    assert found["cavity orientation against the plan"].points == 2.0  # 3° off both: within 5°
    assert found["reaming within 10° of the plan"].points == 1.0
    assert found["cavity diameter against the plan"].points == 1.0  # 47 mm for a 48 mm cup
    assert found["reamer sequence"].points == 1.0 and "44 → 46 → 47" in found["reamer sequence"].measured
    assert found["centre of rotation against the plan"].points == 1.0  # 0 mm for a plan of 2 mm medial
    strict = tmp_path / "strict.yaml"
    strict.write_text("orientation_error_deg: {full: 2, partial: 4, source: our experts}\ncentre_error_mm: {full: 1, partial: 1.5}\n")
    scored = {c.name: c for c in criteria(record, load_thresholds(strict))}
    assert (
        scored["cavity orientation against the plan"].points == 1.0
        and "≤ 2°: 2; ≤ 4°: 1" in scored["cavity orientation against the plan"].rule
    )
    assert scored["centre of rotation against the plan"].points == 0.0
    # a model that cut another size than the one held: the diameter is not the trainee's to score
    ignored = _record(range(1, 19), np.arange(1.0, 19.0), reamer=reamer, cut=[45.8] * 18)
    names = {c.name for c in criteria(ignored)}
    assert "cavity diameter against the plan" not in names and "reamer sequence" in names
    # a cavity reamed through is no cavity to plan, however it was undone: no points for its orientation, centre, diameter
    record.events = [
        {"time_s": 0.1, "kind": "perforated", "detail": "", "frame": 6},
        {"time_s": 0.2, "kind": "undo", "detail": "", "frame": 0},
    ]
    through = {c.name: c for c in criteria(record)}
    for name in ("cavity orientation against the plan", "centre of rotation against the plan", "cavity diameter against the plan"):
        assert through[name].points == 0.0 and through[name].measured.startswith("not a prepared cavity: perforated at 0.1 s, then undone")
    assert through["reamer sequence"].points == 1.0 and through["reaming within 10° of the plan"].points == 1.0
    down = {c.name: c for c in criteria(_record(range(1, 4), [1, 2, 3.0], reamer=[46, 44, 50], cut=[46, 44, 50]))}
    assert down["reamer sequence"].points == 0.0 and "stepped down" in down["reamer sequence"].measured


def test_the_shipped_thresholds_state_their_sources():
    shipped = default_thresholds()
    for name, entry in shipped:
        assert entry.source, name
    assert "Lewinnek" in shipped.safe_zone_fraction.source and "10.1186/s10195-024-00766-2" in shipped.orientation_error_deg.source


def test_case_and_thresholds_files_are_checked_in_one_line(tmp_path, monkeypatch, capsys):
    case = tmp_path / "case.yaml"
    case.write_text("cup_diameter_mm: 52\ninclination_deg: 42\nanteversion_deg: 18\nmedialisation_mm: 3\n")
    assert load_plan(case) == Plan(cup_diameter_mm=52, inclination_deg=42, anteversion_deg=18, medialisation_mm=3)
    as_json = tmp_path / "case.json"
    as_json.write_text(json.dumps({"cup_diameter_mm": 50}))
    assert load_plan(as_json).cup_diameter_mm == 50 and load_plan(as_json).inclination_deg == 40
    bad = {
        "big.json": '{"cup_diameter_mm": 90}',
        "extra.json": '{"cup_size": 50}',
        "list.yaml": "- 1\n- 2\n",
        "broken.json": "{",
        "nan.json": '{"inclination_deg": NaN}',
    }
    for name, text in bad.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ThrsimInputError) as refused:
            load_plan(tmp_path / name)
        assert "\n" not in str(refused.value) and name in str(refused.value)
    (tmp_path / "thresholds.json").write_text('{"safe_zone_fraction": {"full": 0.5, "partial": 0.9}}')
    code, out, err = run_main(
        monkeypatch, capsys, "report", str(tmp_path / "none.h5"), "--json", "--thresholds", str(tmp_path / "thresholds.json")
    )
    assert code == 2 and "partial must be at most full" in err and len(err.strip().splitlines()) == 1 and out == ""
    sessions = tmp_path / "sessions"
    code, out, err = run_main(
        monkeypatch, capsys, "serve", "--plan", str(tmp_path / "big.json"), "--sessions", str(sessions), "--port", "0"
    )
    assert code == 2 and "cup_diameter_mm" in err and len(err.strip().splitlines()) == 1 and not sessions.exists()


@pytest.fixture(scope="module")
def shipped_simulator():
    return ReamingSimulator(threads=1)


def _control(trainer: ReamingTrainer, time_s: float, **message) -> str:
    return trainer.apply_control(parse_reaming_control(message), time_s)


def test_the_trainee_plans_before_reaming_and_swaps_reamers(shipped_simulator):
    shipped_simulator.reset()
    trainer = ReamingTrainer(simulator=shipped_simulator)
    state = trainer.step(0.0)["reaming"]
    assert state["plan"]["cup_diameter_mm"] == 48 and state["plan"]["source"] == "trainee" and not state["plan"]["fixed"]
    assert state["reamer"]["size_mm"] == 44 and state["reamer"]["sizes_mm"][0] == 40 and state["reamer"]["sizes_mm"][-1] == 64
    learned = list(shipped_simulator.model.trained_reamer_mm)
    assert learned == [pytest.approx(2e3 * shipped_simulator.model.card["reamer"]["teeth_radius_m"])]  # from the model card
    assert state["reamer"]["cuts_mm"] == learned[0] and f"trained on {learned[0]:g} mm only" in state["reamer"]["note"]
    _control(trainer, 0.1, type="plan", cup_diameter_mm=50, medialisation_mm=1, superior_shift_mm=0, inclination_deg=42, anteversion_deg=18)
    assert trainer.plan.cup_diameter_mm == 50
    assert _control(trainer, 0.2, type="reamer_size", size_mm=46) == "reamer 46 mm"
    _control(trainer, 0.3, type="run", action="start")
    t = 0.3
    for _ in range(20):
        t += DT
        state = trainer.step(t)["reaming"]
    assert state["plan"]["fixed"] and state["frame"] > 0
    with pytest.raises(ThrsimInputError, match="fixed once reaming has started"):
        _control(
            trainer, t, type="plan", cup_diameter_mm=52, medialisation_mm=0, superior_shift_mm=0, inclination_deg=40, anteversion_deg=15
        )
    _control(trainer, t, type="reamer_size", size_mm=48)  # a swap while reaming pauses first
    assert not trainer.running
    kinds = [(e["kind"], e.get("to_mm")) for e in trainer.events]
    assert kinds == [("plan_set", None), ("reamer_changed", 46), ("start", None), ("pause", None), ("reamer_changed", 48)]
    record = trainer.record()
    assert set(record.reamer_mm) == {46.0} and np.allclose(record.cut_mm, learned[0]) and record.plan["cup_diameter_mm"] == 50


def test_a_model_that_learned_several_sizes_cuts_with_the_nearest(shipped_simulator):
    reamer = shipped_simulator.model.card["reamer"]
    reamer["sizes_mm"] = [44.0, 48.0]  # a card of a model trained on two reamers
    try:
        assert shipped_simulator.cutting_size_mm(45) == 44.0 and shipped_simulator.cutting_size_mm(47) == 48.0
        trainer = ReamingTrainer(simulator=shipped_simulator)
        _control(trainer, 0.0, type="reamer_size", size_mm=48)
        assert trainer.step(0.1)["reaming"]["reamer"]["note"] == ""  # it cuts what is held: nothing to say
    finally:
        del reamer["sizes_mm"]


def test_an_instructors_case_fixes_the_plan_and_the_session_file_keeps_it(tmp_path):
    now = [0.0]
    case = Plan(cup_diameter_mm=54, inclination_deg=45, anteversion_deg=20)
    session = LiveSession(MODES["reaming"], {"side": "left", "seed": 1, "plan": case.model_dump()}, lambda: now[0], tmp_path)
    with pytest.raises(ThrsimInputError, match="case file sets"):
        session.control(json.dumps({"type": "plan", "cup_diameter_mm": 50, "medialisation_mm": 0, "superior_shift_mm": 0,
                                    "inclination_deg": 40, "anteversion_deg": 15}))  # fmt: skip
    assert session.trainer.reamer_mm == 50  # a few millimetres under the cup
    session.control(json.dumps({"type": "run", "action": "start"}))
    for _ in range(12):
        now[0] += DT
        session.tick()
    session.control(json.dumps({"type": "reamer_size", "size_mm": 52}))  # pauses, and the swap is an event
    session.control(json.dumps({"type": "run", "action": "start"}))
    for _ in range(12):
        now[0] += DT
        session.tick()
    path = session.save(tmp_path)
    found = build_assessment(path).metrics
    assert found["plan"]["source"] == "case file" and found["plan"]["cup_diameter_mm"] == 54
    frames = [session.trainer.trace.reamer_mm.count(size) for size in (50.0, 52.0)]
    assert found["reamer_sequence_mm"] == [50.0, 52.0] and found["time_per_reamer_s"] == pytest.approx([n * DT for n in frames])
    page = build_report(path)
    assert "Reaming: against the plan" in page and "Plan set by the case file" in page and "trained on that size only" in page
    replayed = replay_session(path)  # the plan, the refused plan and the swap live again alike
    assert replayed.reproduced and replayed.refused_controls == 1


def test_a_scripted_session_reports_its_confirmed_cup_and_cavity_against_the_plan(tmp_path):
    """Plan a 46 mm cup at the zone's centre, ream at 45°/20° for 40 frames, confirm the cup, end:
    the saved file's report gives the confirmed cup 5° off in both angles and the cavity's floor,
    over- and under-reaming as the final bone (the trainer's, read directly) has them."""
    now = [0.0]
    session = LiveSession(MODES["reaming"], {"side": "right", "seed": 1}, lambda: now[0], tmp_path)

    def send(**message) -> str:
        return session.control(json.dumps(message))[1]

    send(type="plan", cup_diameter_mm=46, medialisation_mm=0, superior_shift_mm=0, inclination_deg=40, anteversion_deg=15)
    send(type="reamer", inclination_deg=45, anteversion_deg=20)
    send(type="run", action="start")
    while session.trainer.frames_run < 40 and now[0] < 10.0:
        now[0] += DT
        session.tick()
    send(type="run", action="pause")
    assert send(type="confirm_cup").startswith("cup orientation confirmed at 45.0° / 20.0°")
    sim = session.trainer.simulator
    removed = sim.alpha < sim.model.threshold
    centroids = sim.right_mesh.centroids * 1e3  # the plan's centre is the patch frame's origin, its axis +z
    distance = np.linalg.norm(centroids, axis=1)
    inside = ~removed & (distance < 23.0) & (centroids[:, 2] < 0.0)
    expected = {
        "cavity_depth_error_mm": float(np.max(-centroids[removed, 2])) - 23.0,
        "over_reaming_mm": max(0.0, float(np.max(distance[removed])) - 23.0),
        "under_reaming_mm": float(np.max(23.0 - distance[inside])),
    }
    path = session.save(tmp_path)
    found = build_assessment(path).metrics
    assert found["confirmed_inclination_error_deg"] == pytest.approx(5.0, abs=1e-6)
    assert found["confirmed_anteversion_error_deg"] == pytest.approx(5.0, abs=1e-6)
    for name, value in expected.items():
        assert found[name] == pytest.approx(value, abs=1e-4), name
    assert found["medial_wall_remaining_mm"] is None
    page = build_report(path)
    assert "45.0°</td><td>5.0°" in page and "20.0°</td><td>5.0°" in page
    assert f"<td>{expected['cavity_depth_error_mm']:.1f} mm</td>" in page and f"<td>{expected['under_reaming_mm']:.1f} mm</td>" in page
    assert "not modelled (the bone patch has no medial wall)" in page


def test_serve_takes_the_case_and_scores_its_reports_against_the_thresholds(tmp_path):
    case = tmp_path / "case.json"
    case.write_text(json.dumps({"cup_diameter_mm": 56, "inclination_deg": 45}))
    assert MODES["reaming"].session_settings(ServeSettings(plan=load_plan(case)))["plan"]["cup_diameter_mm"] == 56
    thresholds = tmp_path / "thresholds.yaml"
    thresholds.write_text(
        "within_10deg_fraction: {full: 0.95, partial: 0.85, source: our experts}\norientation_error_deg: {full: 1, partial: 2}\n"
    )
    sessions = tmp_path / "sessions"
    sessions.mkdir()
    served = ServedTrainer(sessions, "--plan", str(case), "--thresholds", str(thresholds), timeout=180.0)  # a loaded machine starts slowly
    try:
        with connect(f"ws://127.0.0.1:{served.port}/ws/reaming", open_timeout=10) as ws:
            next_of_type(ws, "hello")
            ws.send(json.dumps({"type": "trainee", "id": "Resident 3"}))
            state = next_of_type(ws, "state")["reaming"]
            assert state["plan"]["cup_diameter_mm"] == 56 and state["plan"]["source"] == "case file" and state["plan"]["fixed"]
            assert state["reamer"]["size_mm"] == 52
            ws.send(json.dumps({"type": "run", "action": "start"}))
            assert wait_for(lambda: next_of_type(ws, "state")["reaming"]["frame"] > 5, timeout=30)
            ws.send(json.dumps({"type": "end_session"}))
            saved = next_of_type(ws, "session_saved")
        with urllib.request.urlopen(served.url + saved["report"], timeout=60) as response:
            page = response.read().decode()
        record = {
            path: urllib.request.urlopen(served.url + path, timeout=60).read().decode() for path in ("/sessions", "/trainee/resident%203")
        }
        exported = json.loads(urllib.request.urlopen(served.url + "/api/sessions.json", timeout=60).read())
    finally:
        served.stop()
    # the session list and the trainee's page judge with the thresholds the server loaded, not the shipped ones
    path = sessions / f"{saved['session']}.h5"
    instructors, shipped = build_assessment(path, load_thresholds(thresholds)), build_assessment(path)
    assert instructors.score != shipped.score  # the cavity's axis is 5° off the case's 45°: within 5°, not within 1°
    (row,) = exported["sessions"]
    assert row["score"] == instructors.score and f"<td>{instructors.score:g} / {instructors.max_score:g}</td>" in record["/sessions"]
    assert exported["competency"]["within_10deg_fraction"] == [0.95, "min"] and exported["competency"]["inclination_error_deg"] == [
        1,
        "max",
    ]
    assert "competent: ≥ 0.95" in record["/trainee/resident%203"] and "competent: ≤ 1<" in record["/trainee/resident%203"]
    assert "≥ 95 %: 1; ≥ 85 %: 0.5" in page  # the served report scored against the instructor's thresholds
    assert "Plan set by the case file" in page
