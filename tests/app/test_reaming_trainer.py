"""The reaming trainer's logic with a real (tiny) trained model: frames follow the running time,
pause, undo and reset, the force sources, the patch in the pelvis, the session group and replay."""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest

from thrsim.app.controls import parse_reaming_control
from thrsim.app.modes import MODES
from thrsim.app.reaming import DISPLAY_LEVELS, MAX_FRAMES_PER_TICK, ReamingTrainer
from thrsim.errors import ThrsimInputError
from thrsim.learn.simulator import ReamingSimulator
from thrsim.nav.anatomy import local_axis_from_angles

STEP = 1 / 60


class Clock:
    def __init__(self, trainer: ReamingTrainer):
        self.trainer, self.now, self.state = trainer, 0.0, None

    def run(self, seconds: float, step: float = STEP) -> dict:
        for _ in range(int(round(seconds / step))):
            self.now += step
            self.state = self.trainer.step(self.now)
        return self.state

    def control(self, message: dict) -> str:
        return self.trainer.apply_control(parse_reaming_control(message), self.now)


@pytest.fixture(scope="module")
def shipped_simulator():
    return ReamingSimulator(threads=1)


@pytest.fixture
def clock(shipped_simulator):
    # the shipped model on the default mesh: its patch lasts for seconds of reaming near the axis
    shipped_simulator.reset()
    trainer = ReamingTrainer(simulator=shipped_simulator)
    clock = Clock(trainer)
    clock.control({"type": "reamer", "inclination_deg": 45, "anteversion_deg": 20})
    return clock


def test_frames_follow_the_running_time_and_bone_is_removed(clock):
    state = clock.run(0.5)
    assert state["reaming"]["frame"] == 0 and not state["reaming"]["running"]
    assert clock.control({"type": "run", "action": "start"}) == "reaming"
    state = clock.run(1.0)
    reaming = state["reaming"]
    assert abs(reaming["frame"] - clock.trainer.frame_rate_hz) <= 1 and reaming["behind_frames"] == 0
    volumes = clock.trainer.trace.removed_volume_mm3
    assert volumes[-1] > 0 and all(b >= a for a, b in pairwise(volumes))  # removal never undoes itself
    assert reaming["removed"] > 0 and reaming["depth_mm"] > 0 and reaming["removed_volume_mm3"] == pytest.approx(volumes[-1])
    assert reaming["gamma_deg"] == pytest.approx(
        math.degrees(math.acos(local_axis_from_angles(40, 15) @ local_axis_from_angles(45, 20))), abs=1e-6
    )
    clock.control({"type": "run", "action": "pause"})
    frames = reaming["frame"]
    assert clock.run(0.5)["reaming"]["frame"] == frames


def test_a_slow_tick_steps_at_most_one_frame_and_says_it_fell_behind(clock):
    clock.control({"type": "run", "action": "start"})
    state = clock.run(1.0, step=0.1)  # 10 ticks, 6 frames due each
    assert state["reaming"]["frame"] == 10 and state["reaming"]["behind_frames"] == 50


def test_a_session_recorded_with_two_frames_a_tick_is_made_again_with_two():
    from thrsim.app.modes import MODES

    trainer = MODES["reaming"].make_trainer({"mode": "reaming", "max_frames_per_tick": 2, "model": None})
    assert trainer.max_frames_per_tick == 2 and trainer.settings()["max_frames_per_tick"] == 2
    assert MODES["reaming"].make_trainer({"mode": "reaming", "model": None}).max_frames_per_tick == MAX_FRAMES_PER_TICK == 1


def _steered_run(simulator, with_early: bool) -> tuple[list[dict], dict[int, dict]]:
    """One second of reaming with the reamer re-aimed before every tick: each tick's state and,
    with ``with_early``, the early states by tick."""
    clock = Clock(ReamingTrainer(simulator=simulator))
    clock.control({"type": "run", "action": "start"})
    states: list[dict] = []
    early: dict[int, dict] = {}

    def take(state: dict) -> None:
        assert len(states) not in early  # at most once per tick
        early[len(states)] = state

    for k in range(60):
        clock.control({"type": "reamer", "inclination_deg": 40 + 5 * math.sin(k / 5), "anteversion_deg": 20})
        clock.now += STEP
        states.append(clock.trainer.step(clock.now, take if with_early else None))
    return states, early


def test_a_tick_with_frames_hands_out_the_new_pose_first_and_steps_the_same(shipped_simulator):
    states, early = _steered_run(shipped_simulator, True)
    before = [0] + [s["reaming"]["frame"] for s in states]
    stepped = {k for k, s in enumerate(states) if s["reaming"]["frame"] > before[k]}
    assert set(early) == stepped and len(stepped) >= 55  # every tick that stepped a frame, and only those
    for k, first in early.items():
        assert first["reaming"]["frame"] == before[k]  # the bone before this tick's frames ...
        assert first["reaming"]["gamma_deg"] == states[k]["reaming"]["gamma_deg"]  # ... under this tick's pose
        assert first["reaming"]["removed"] <= states[k]["reaming"]["removed"]
    plain, none = _steered_run(shipped_simulator, False)
    assert not none

    def without_events(state: dict) -> dict:
        return {k: v for k, v in state["reaming"].items() if k not in ("events", "step_ms")}

    assert [without_events(s) for s in plain] == [without_events(s) for s in states]  # a replay (no early) lives it alike
    handed_out = [e for k, s in enumerate(states) for e in (early[k]["reaming"]["events"] if k in early else []) + s["reaming"]["events"]]
    assert handed_out == [e for s in plain for e in s["reaming"]["events"]]  # every event once, in order


def test_undo_goes_back_one_second_and_reset_restores_the_bone(clock):
    trainer = clock.trainer
    clock.control({"type": "run", "action": "start"})
    clock.run(1.5)  # 90 frames: the shipped model reams this aim through after about 110
    frames = trainer.frames_run
    assert trainer.running and frames == 90
    assert clock.control({"type": "run", "action": "undo"}).startswith("undid 60")
    assert trainer.frames_run == frames - 60 and not trainer.running
    assert trainer.simulator.frame == frames - 60
    # the bone is as it was at that frame
    assert trainer.simulator.removed.sum() == trainer.trace.removed[trainer.trace.frame.index(frames - 60)]
    clock.control({"type": "run", "action": "reset"})
    state = clock.run(0.1)
    assert state["reaming"]["frame"] == 0 and state["reaming"]["removed"] == 0
    assert [e["kind"] for e in trainer.events] == ["start", "undo", "restore"]


def test_a_force_sensor_overrides_the_page_while_it_streams(clock):
    trainer = clock.trainer
    clock.control({"type": "force", "newton": 150})
    assert clock.run(0.1)["reaming"]["force_n"] == 150
    trainer.apply_force(300.0, clock.now)
    state = clock.run(0.2)
    assert state["reaming"]["force_n"] == 300 and state["reaming"]["force_source"] == "sensor"
    state = clock.run(0.5)
    assert state["reaming"]["force_n"] == 150 and state["reaming"]["force_source"] == "page"
    for bad in (-1.0, float("nan"), 1e4):
        with pytest.raises(ThrsimInputError, match="force reading"):
            trainer.apply_force(bad, clock.now)
    for message in ({"type": "force", "newton": 500}, {"type": "run", "action": "explode"}, {"type": "probe", "action": "kick"}):
        with pytest.raises(ThrsimInputError):
            parse_reaming_control(message)


def test_reaming_holds_while_the_reamer_cannot_be_measured(clock):
    clock.control({"type": "run", "action": "start"})
    clock.run(0.2)
    frames = clock.trainer.frames_run
    clock.control({"type": "camera", "azimuth_deg": -130, "elevation_deg": 30, "distance_mm": 1600})  # behind the patient
    state = clock.run(0.5)
    assert not state["tools"]["Reamer"]["tracked"] and state["reaming"]["frame"] == frames
    assert "not measured" in state["reaming"]["note"]


def test_the_patch_sits_in_the_acetabulum_along_the_safe_zone_centre(tiny_model):
    for side, handedness in (("right", 1.0), ("left", -1.0)):
        trainer = ReamingTrainer(side=side, simulator=ReamingSimulator(tiny_model, threads=1))
        placement = trainer.patch_to_model
        linear = placement[:3, :3]
        assert np.allclose(linear.T @ linear, np.eye(3), atol=1e-12) and np.sign(np.linalg.det(linear)) == handedness
        assert np.allclose(placement[:3, 3], trainer.navigation.acetabulum_model)
        # the patch's +z, out of the acetabulum, is the cup axis at 40° / 15° in this hip's APP
        cup = trainer.navigation.true_app_model.to_local(linear @ np.array([0.0, 0.0, 1.0]))
        assert np.allclose(cup, local_axis_from_angles(40, 15), atol=1e-12)
    scene = trainer.scene()["reaming"]
    assert scene["available"] and scene["elements"] == trainer.simulator.n_elements and scene["display_levels"] == DISPLAY_LEVELS


def test_display_levels_mark_removed_elements_and_quantise_alpha(clock):
    clock.control({"type": "run", "action": "start"})
    clock.run(0.05)
    levels = clock.trainer.display_levels()
    removed = clock.trainer.simulator.removed
    assert removed.any() and not removed.all()
    assert levels.dtype == np.uint8 and np.array_equal(levels == 0, removed)
    assert levels[~removed].min() >= 1 and levels.max() <= DISPLAY_LEVELS


def test_without_a_model_the_mode_says_why_and_navigation_still_works():
    trainer = MODES["reaming"].make_trainer({"side": "right", "seed": 0, "model": "/nonexistent/model"})
    state = trainer.step(STEP)
    assert not state["reaming"]["available"] and "model" in state["reaming"]["unavailable"]
    assert state["tools"]["Reamer"]["tracked"] in (True, False) and "angles" in state
    with pytest.raises(ThrsimInputError, match="unavailable"):
        trainer.apply_control(parse_reaming_control({"type": "run", "action": "start"}), STEP)
    assert (
        trainer.apply_control(parse_reaming_control({"type": "reamer", "inclination_deg": 40, "anteversion_deg": 15}), STEP)
        == "reamer steered"
    )


def test_a_reaming_session_is_saved_read_back_and_replayed_exactly(tmp_path):
    from thrsim.app.live import LiveSession
    from thrsim.app.replay import replay_session
    from thrsim.session.file import read_session
    from thrsim.session.reaming import read_reaming

    now = [0.0]
    session = LiveSession(MODES["reaming"], {"side": "left", "seed": 3}, lambda: now[0], tmp_path)
    session.control('{"type": "reamer", "inclination_deg": 42, "anteversion_deg": 18}')
    session.control('{"type": "run", "action": "start"}')
    for k in range(40):
        now[0] += STEP
        if k == 10:
            session.force(280.0, now[0])
        if k == 20:
            with pytest.raises(ThrsimInputError, match="display's pose"):  # logged, and refused again in the replay
                session.control('{"type": "calibration", "action": "start"}')
        session.tick()
    path = session.save()
    record = read_reaming(read_session(path).groups["reaming"])
    live = session.trainer.record()
    assert record.side == "left" and record.mesh_digest == session.trainer.simulator.model.graph.digest
    assert np.array_equal(record.removed, live.removed) and np.array_equal(record.final_alpha, live.final_alpha)
    assert record.force_n[5] == 230 and record.force_n[15] == 280  # the sensor's reading, while fresh
    assert [e["kind"] for e in record.events] == ["start"] and record.navigation.side == "left"
    outcome = replay_session(path)
    assert outcome.reproduced and outcome.refused_controls == 1
    import h5py

    with h5py.File(path, "r+") as f:  # as if reamed on another mesh
        f["reaming"].attrs["mesh_digest"] = "0" * 64
    with pytest.raises(ThrsimInputError, match="reamed on mesh 000000000000"):
        replay_session(path)


def test_the_report_maps_the_cavity_against_the_planned_hemisphere(tmp_path):
    from thrsim.app.live import LiveSession
    from thrsim.config import BonePatchConfig
    from thrsim.geometry.bone_patch import generate_bone_patch
    from thrsim.report import build_report
    from thrsim.report.reaming import cavity_map
    from thrsim.session.reaming import ReamingRecord

    mesh = generate_bone_patch(BonePatchConfig(element_size_mm=0.45))
    centroids = mesh.centroids
    radius = np.linalg.norm(centroids, axis=1)
    outer = np.isin(mesh.tets, mesh.node_sets["outer"]).sum(axis=1) >= 3
    geometry = {
        "centroids_m": centroids,
        "outer": outer,
        "inner_radius_m": 0.022,
        "outer_radius_m": 0.024,
        "teeth_radius_m": 0.0229,
        "threshold": 0.3,
    }

    def record(removed: np.ndarray) -> ReamingRecord:
        empty = np.zeros((0, 3))
        nav = ReamingTrainer().navigation.record()
        return ReamingRecord(
            "right",
            {},
            "",
            np.eye(4),
            np.zeros(0),
            np.zeros(0, int),
            np.zeros(0),
            empty,
            empty,
            np.zeros(0, int),
            np.zeros(0),
            np.zeros(0),
            empty,
            [],
            (150.0, 310.0),
            np.where(removed, 0.0, 0.8).astype(np.float32),
            0,
            nav,
            geometry,
        )

    planned = cavity_map(record(radius < 0.0229))
    assert planned["fractions"]["on plan"] > 0.9 and planned["fractions"]["perforated"] == 0
    assert np.nanmedian(planned["error_mm"]) == pytest.approx(0.0, abs=0.45)  # cut to the reamer's 22.9 mm: on it
    shallow = cavity_map(record(radius < 0.0223))
    assert shallow["fractions"]["under-reamed"] + shallow["fractions"]["not reached"] > 0.9
    through = cavity_map(record((radius < 0.0229) | (np.linalg.norm(centroids[:, :2], axis=1) < 2e-3)))
    assert 0 < through["fractions"]["perforated"] < 0.2 and through["fractions"]["on plan"] > 0.6

    now = [0.0]
    session = LiveSession(MODES["reaming"], {"side": "right", "seed": 1}, lambda: now[0], tmp_path)
    session.control('{"type": "reamer", "inclination_deg": 45, "anteversion_deg": 20}')
    session.control('{"type": "run", "action": "start"}')
    for _ in range(30):
        now[0] += STEP
        session.tick()
    report = build_report(session.save())
    for title in (
        "Reaming: removal, depth and push",
        "Reaming: the final cavity",
        "Reaming: orientation while cutting",
        "no perforation or breach",
        "safe zone while cutting",
        "Reaming: errors and corrections",
    ):
        assert title in report
    assert report.count("data:image/png;base64,") >= 2


def test_reaming_pauses_where_the_shipped_model_reams_through_the_bone(shipped_simulator):
    # aimed 15° off the patch's axis: the solver's γ 15° cases at 230 N break through after 92-99 frames
    shipped_simulator.reset()
    clock = Clock(ReamingTrainer(simulator=shipped_simulator))
    clock.control({"type": "reamer", "inclination_deg": 55, "anteversion_deg": 15})
    assert clock.run(0.1)["reaming"]["gamma_deg"] == pytest.approx(15.0, abs=1.0)
    clock.control({"type": "run", "action": "start"})
    state = clock.run(3.0)
    trainer = clock.trainer
    ends = [e for e in trainer.events if e["kind"] in ("perforated", "passed_through")]
    assert len(ends) == 1 and not state["reaming"]["running"]
    assert 60 <= trainer.frames_run <= 150 and ends[0]["frame"] == trainer.frames_run
    assert clock.run(0.5)["reaming"]["frame"] == trainer.frames_run  # holds there
    assert clock.control({"type": "run", "action": "undo"}).startswith("undid 60")


def test_the_state_carries_the_plans_cup_and_the_bone_left_before_breaking_through(clock):
    """The plan's cup in the model frame: at the native centre shifted by the plan, its axis the
    plan's angles in the pelvis's APP; the bone left before the patch's far face shrinks as the
    reamer goes in, and the patch has no medial wall to measure."""
    trainer = clock.trainer
    state = clock.run(0.1)["reaming"]
    plan = state["plan"]
    assert plan["cup_diameter_mm"] == 48.0 and plan["source"] == "trainee"
    assert np.allclose(plan["centre_m"], trainer.navigation.acetabulum_model)
    assert np.allclose(trainer.navigation.true_app_model.to_local(plan["axis"]), local_axis_from_angles(40, 15))
    clock.control(
        {
            "type": "plan",
            "cup_diameter_mm": 50,
            "medialisation_mm": 3,
            "superior_shift_mm": -2,
            "inclination_deg": 45,
            "anteversion_deg": 20,
        }
    )
    plan = clock.run(0.1)["reaming"]["plan"]
    app = trainer.navigation.true_app_model
    shift = app.to_local(np.array(plan["centre_m"]) - trainer.navigation.acetabulum_model) * 1e3  # lateral, anterior, inferior (mm)
    assert np.allclose(shift, [-3.0, 0.0, 2.0], atol=1e-9)
    assert np.allclose(app.to_local(plan["axis"]), local_axis_from_angles(45, 20))
    assert state["bone_left_mm"] is None  # the reamer has no position until it reams
    assert state["medial_wall_modelled"] is False and state["medial_wall_remaining_mm"] is None
    assert state["cutting_layer"] is None  # the patch is one layer
    clock.control({"type": "run", "action": "start"})
    left = [clock.run(0.25)["reaming"]["bone_left_mm"] for _ in range(4)]
    shell_mm = 2.0  # the patch's thickness: its outer face is the one a perforation breaks through
    assert all(value is not None and 0 <= value < shell_mm for value in left)
    assert left[-1] < left[0] and np.all(np.diff(left) <= 1e-9)
    assert clock.state["reaming"]["medial_wall_remaining_mm"] is None  # never a number for a wall the patch lacks
    assert clock.state["reaming"]["edge_left_mm"] is None  # the patch's cut edge is its far face: bone_left_mm's
    assert clock.state["reaming"]["cutting_layer"] is None


def test_a_bone_with_a_medial_wall_reports_what_is_left_of_it_and_records_it(clock, monkeypatch):
    """A mesh with a ``medial_wall`` face (here the patch's outer face named so): the state gives the
    bone left before it as the medial wall's, and the record keeps it per frame for the report."""
    from dataclasses import replace

    from thrsim.geometry.mesh import MEDIAL_WALL, OUTER
    from thrsim.learn.simulator import ReamingSimulator
    from thrsim.report.reaming_metrics import metrics

    mesh = clock.trainer.simulator.right_mesh
    walled = replace(mesh, node_sets={**mesh.node_sets, MEDIAL_WALL: mesh.node_sets[OUTER]})
    monkeypatch.setattr(ReamingSimulator, "right_mesh", property(lambda self: walled))
    clock.control({"type": "run", "action": "start"})
    state = clock.run(0.5)["reaming"]
    assert state["medial_wall_modelled"] and state["medial_wall_remaining_mm"] == state["bone_left_mm"] is not None
    record = clock.trainer.record()
    assert record.medial_wall_mm is not None and len(record.medial_wall_mm) == len(record.frame)
    assert record.medial_wall_mm[-1] == pytest.approx(state["bone_left_mm"])
    assert metrics(record)["medial_wall_remaining_mm"] == pytest.approx(record.medial_wall_mm.min())


def test_the_cutting_layer_is_what_most_of_a_frames_removed_bone_is_made_of(shipped_simulator):
    from dataclasses import replace

    from thrsim.app.reaming import cutting_layer

    mesh = shipped_simulator.right_mesh
    assert cutting_layer(mesh, np.array([0, 1, 2]), None) is None  # one material: no layer to tell
    material = np.zeros(mesh.n_tets, dtype=np.uint8)
    material[100:] = 1
    layered = replace(mesh, material=material, material_names=("cortical", "cancellous"))
    assert cutting_layer(layered, np.array([0, 1, 2, 150]), None) == "cortical"
    assert cutting_layer(layered, np.array([50, 150, 160]), "cortical") == "cancellous"
    assert cutting_layer(layered, np.array([], dtype=np.int64), "cancellous") == "cancellous"  # nothing removed: as before
