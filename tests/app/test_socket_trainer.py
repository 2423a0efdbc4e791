"""The reaming trainer on the whole socket, with a real (tiny) whole-socket model: the case's socket
meshed and placed, the trainee's reamers cut, each frame's reaction and torque traced and shown,
inputs outside what the model learned are events, the fast contact model gives what the next frame
records, and a session saved to its HDF5 file replays exactly and reports what lay out of range."""

from __future__ import annotations

import json

import numpy as np
import pytest

from thrsim.app.live import LiveSession
from thrsim.app.modes import MODES
from thrsim.app.reaming import SOCKET_IN_PATCH
from thrsim.app.replay import replay_session
from thrsim.config import SafeZone
from thrsim.io.haptic import ContactForce
from thrsim.nav.bone_frame import patch_in_app
from thrsim.report import build_report
from thrsim.session.file import read_session
from thrsim.session.plan import Plan
from thrsim.session.reaming import read_reaming

pytestmark = pytest.mark.timeout(600)

STEP = 1 / 60
#: the coarsest socket the trainer meshes: these tests check behaviour, not resolution
ELEMENT_MM = 5.0


class Clock:
    """A live session of a whole-socket model on a clock the test moves."""

    def __init__(self, folder, model, **settings):
        self.now = 0.0
        settings = {"side": "right", "seed": 1, "model": str(model), "socket_element_size_mm": ELEMENT_MM, **settings}
        self.session = LiveSession(MODES["reaming"], settings, lambda: self.now, folder)
        self.trainer = self.session.trainer
        self.states: list[dict] = []

    def control(self, **message) -> str:
        return self.session.control(json.dumps(message))[1]

    def run(self, seconds: float) -> dict:
        for _ in range(int(round(seconds / STEP))):
            self.now += STEP
            self.states.append(self.session.tick())
        return self.states[-1]


def test_the_cases_socket_is_meshed_turned_into_the_patch_frame_and_reamed_with_its_bone(tiny_socket_model, tmp_path):
    case = Plan(native_socket_mm=50.0, cancellous="osteoporotic")
    clock = Clock(tmp_path, tiny_socket_model, plan=case.model_dump())
    simulator = clock.trainer.simulator
    mesh = simulator.right_mesh
    assert simulator.socket and mesh.material_names == ("cortical", "cancellous") and mesh.n_tets > 1000
    articular = np.linalg.norm(mesh.nodes[mesh.node_sets["articular"]], axis=1)
    assert np.median(articular) * 1e3 == pytest.approx(25.0, abs=0.3)  # the case's 50 mm socket
    # the socket's dome (its frame's +y) lies superior in the hip: the APP's superior direction across the socket's axis
    axes = patch_in_app(SafeZone())
    superior = np.array([0.0, 0.0, -1.0]) - (np.array([0.0, 0.0, -1.0]) @ axes[:, 2]) * axes[:, 2]
    assert axes @ SOCKET_IN_PATCH[:, 1] == pytest.approx(superior / np.linalg.norm(superior))
    assert np.linalg.det(SOCKET_IN_PATCH) == pytest.approx(1.0)  # turned, not mirrored
    settings = clock.trainer.settings()["model"]
    assert settings["bone"] == "socket" and settings["mesh_digest"] == simulator.model.graph.digest
    assert clock.trainer.plan.cancellous == "osteoporotic"
    assert clock.trainer.medial_wall_modelled()  # the socket's medial wall, not the patch's far face


def record_has_no_push_range(trainer) -> bool:
    """A socket session records no trained push range: the report has no share of time outside one."""
    return trainer.record().trained_force_n is None and trainer.settings()["model"]["trained_force_n"] is None


def test_the_reamers_cut_forces_are_traced_and_shown_and_out_of_range_inputs_are_events(tiny_socket_model, tmp_path):
    clock = Clock(tmp_path, tiny_socket_model)
    trainer, learned = clock.trainer, clock.trainer.simulator.model
    first = trainer.reamer_mm
    clock.control(type="force", newton=400)
    clock.control(type="run", action="start")
    running = clock.run(0.3)["reaming"]
    clock.control(type="reamer_size", size_mm=first + 2)  # pauses, the next reamer placed clear of the bone
    assert clock.run(0.1)["reaming"]["contact"] is None  # paused: nothing to feel
    clock.control(type="run", action="start")
    state = clock.run(0.3)["reaming"]
    trace = trainer.trace
    frames = len(trace.frame)
    assert frames >= 30
    # the trainee's sizes, cut by the simulator (it cuts any size a whole-socket model is given)
    assert trace.cut_mm == trace.reamer_mm and set(trace.reamer_mm) == {first, first + 2}
    assert np.isfinite(trace.reaction_n).all() and np.isfinite(trace.motor_torque_n_m).all()
    # each state shows the last frame's force and hands on every frame's since the one before
    assert (state["reaction_n"], state["motor_torque_n_m"]) == (trace.reaction_n[-1], trace.motor_torque_n_m[-1])
    handed = [f for s in clock.states for f in s["reaming"]["frame_forces"]]
    assert [f["frame"] for f in handed] == trace.frame
    assert [f["reaction_n"] for f in handed] == trace.reaction_n
    # the synthetic cases were reamed with one reamer: both reamers lie outside, each said once; a
    # socket model reads the feed the push balances, not the push, so 400 N is no input out of range
    assert first + 2 not in learned.trained_reamer_mm
    kinds = [e["kind"] for e in trainer.events]
    assert "push_out_of_range" not in kinds and kinds.count("reamer_out_of_range") == 2
    assert record_has_no_push_range(trainer)
    said = [e for e in trainer.events if e["kind"] == "reamer_out_of_range"]
    assert [e["reamer_mm"] for e in said] == [first, first + 2] and said[0]["trained_reamer_mm"] == list(learned.trained_reamer_mm)
    # the tiny model's law learned on the synthetic block's small contact: the whole socket's is larger, flagged and said once
    assert running["out_of_range"] == state["out_of_range"] == ["contact", "reamer size"]
    contact = [e for e in trainer.events if e["kind"] == "contact_out_of_range"]
    assert len(contact) == 1 and contact[0]["contact_mm2"] > contact[0]["trained_contact_mm2"][1] == learned.trained_law_contact_mm2[1]
    record = trainer.record()
    assert np.array_equal(record.reaction_n, trace.reaction_n) and np.array_equal(record.cut_mm, trace.cut_mm)


def test_the_fast_contact_model_gives_what_the_next_frame_records(tiny_socket_model, tmp_path):
    clock = Clock(tmp_path, tiny_socket_model)
    clock.control(type="run", action="start")
    force = ContactForce()
    predicted = []
    for push in (400.0, 150.0, 0.0, 400.0):
        clock.control(type="force", newton=push)
        state = clock.run(STEP)["reaming"]
        force.follow(state["contact"])
        assert state["contact"]["force_n"] == push
        predicted.append(force.now())
        force.push(push)  # a sensor's reading, newer than the law: the same push, the same force
        assert force.now() == predicted[-1]
        clock.run(STEP)
    reactions = list(zip(clock.trainer.trace.reaction_n, clock.trainer.trace.motor_torque_n_m, strict=True))
    assert np.array(predicted) == pytest.approx(np.array(reactions[1::2]), rel=1e-9)
    force.follow(None)
    assert force.now() == (0.0, 0.0)


def test_a_whole_socket_session_is_saved_and_replayed_exactly(tiny_socket_model, tmp_path):
    clock = Clock(tmp_path, tiny_socket_model, side="left")
    clock.control(type="reamer", inclination_deg=45, anteversion_deg=20)
    clock.control(type="force", newton=400)
    clock.control(type="run", action="start")
    clock.run(0.2)
    clock.control(type="reamer_size", size_mm=clock.trainer.reamer_mm + 1)
    clock.control(type="run", action="start")
    clock.run(0.2)
    path = clock.session.save()
    record = read_reaming(read_session(path).groups["reaming"])
    live = clock.trainer.record()
    assert record.reaction_n is not None and np.array_equal(record.reaction_n, live.reaction_n)
    assert np.array_equal(record.motor_torque_n_m, live.motor_torque_n_m) and np.array_equal(record.cut_mm, live.cut_mm)
    assert {"reamer_out_of_range", "reamer_changed"} <= {e["kind"] for e in record.events}
    outcome = replay_session(path, model=tiny_socket_model)
    assert outcome.reproduced and outcome.events > 3
    report = build_report(path, None)  # its errors and corrections list the inputs outside what the model learned
    assert "reamer out of range" in report and "push out of range" not in report
