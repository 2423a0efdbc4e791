"""The medial wall on a real whole-socket session: the shipped socket model on the native 46 mm
socket meshed at 3 mm, the 48 mm reamer pushed at 400 N at the safe zone's centre, which breaks
into the pelvis through the medial wall. Every state's bone left before the wall is checked against
the test's own reading of the socket's mesh (the remaining elements touching the wall, all their
nodes; 0 once one is gone, the frame the simulator ends as a breach); the trace and the report
give the same figure, so a report never says "0 mm left" of a breach and more of the same bone."""

from __future__ import annotations

import numpy as np
import pytest
from app_helpers import SocketSession, own_bone_left

from thrsim.app.reaming import BREAK_CAUTION_MM, BREAK_WARNING_MM, socket_in_patch
from thrsim.geometry.mesh import MEDIAL_WALL
from thrsim.report import build_report
from thrsim.report.reaming import criteria
from thrsim.report.reaming_metrics import metrics
from thrsim.session.file import read_session
from thrsim.session.reaming import read_reaming

pytestmark = pytest.mark.timeout(900)

ELEMENT_MM = 3.0  # fine enough that the reamer reaches the wall before the modelled bone's cut edge
REAMER_MM, PUSH_N = 48, 400.0
FRAMES_AFTER_UNDO = 6


def _ream_until_it_stops(session: SocketSession, mesh, frames: int = 120) -> list[dict]:
    """Ream until the simulator pauses; each state with the test's own figures: the bone left by the
    element rule, and the old reading (to the wall's own nodes only, the elements ignored)."""
    bone_left = own_bone_left(mesh, MEDIAL_WALL)
    face_nodes = mesh.nodes[mesh.node_sets[MEDIAL_WALL]]
    teeth_m = REAMER_MM / 2e3
    states = []
    for _ in range(frames):
        state = session.tick()
        centre = session.live.trainer._reamer_position
        if centre is not None:
            face = (np.linalg.norm(face_nodes - centre, axis=1).min() - teeth_m) * 1e3
            states.append({**state, "own_bone_left_mm": bone_left(session.live.trainer, teeth_m), "face_nodes_mm": face})
        if not state["running"]:
            break
    return states


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """The breach saved as it was, and the same session saved again after undoing it and reaming less."""
    folder = tmp_path_factory.mktemp("socket-wall")
    mesh = socket_in_patch(46.0, ELEMENT_MM)  # the same socket meshed again, independently of the trainer
    breach = SocketSession(folder, ELEMENT_MM)
    breach.send(type="force", newton=PUSH_N)
    breach.send(type="reamer_size", size_mm=REAMER_MM)
    breach.send(type="run", action="start")
    states = _ream_until_it_stops(breach, mesh)
    breached = read_reaming(read_session(breach.live.save(folder)).groups["reaming"])
    undone = SocketSession(folder, ELEMENT_MM)  # the same inputs, then U
    undone.send(type="force", newton=PUSH_N)
    undone.send(type="reamer_size", size_mm=REAMER_MM)
    undone.send(type="run", action="start")
    _ream_until_it_stops(undone, mesh)
    undone.send(type="run", action="undo")  # back to the intact bone (the breach came within the undo's second)
    undone.send(type="run", action="start")
    for _ in range(FRAMES_AFTER_UNDO):  # ream again, stopping short of the wall
        undone.tick()
    undone.send(type="run", action="pause")
    path = undone.live.save(folder)
    return states, breached, path


def test_the_bone_left_before_the_medial_wall_is_to_its_remaining_elements(session):
    states, _, _ = session
    assert len(states) > 3
    for state in states:
        assert state["medial_wall_modelled"] and state["bone_left_mm"] == pytest.approx(state["own_bone_left_mm"], abs=1e-9)
        assert state["medial_wall_remaining_mm"] == state["bone_left_mm"]
    left = [state["bone_left_mm"] for state in states]
    assert left[0] > 2 * BREAK_WARNING_MM and np.all(np.diff(left) <= 1e-9)  # the reamer only goes in
    # the frame the simulator ends as a breach says 0 left (or a frame before, once the teeth reach a wall
    # element's inner nodes); the wall's own nodes were still beyond the teeth
    last = states[-1]
    assert [e["kind"] for e in last["events"]].count("medial_wall_breached") == 1 and last["bone_left_mm"] == 0.0
    assert last["face_nodes_mm"] > 0.0
    # the element rule never gives more bone than the wall's own nodes, and the amber caution showed with bone still left
    assert all(state["bone_left_mm"] <= state["face_nodes_mm"] + 1e-9 for state in states)
    assert any(0.0 < state["bone_left_mm"] < BREAK_CAUTION_MM for state in states[:-1])
    assert not any(e["kind"] == "medial_wall_breached" for state in states[:-1] for e in state["events"])


def test_the_trace_and_the_report_give_the_same_figure_as_the_warning(session):
    states, breached, _ = session
    assert breached.medial_wall_mm is not None and len(breached.medial_wall_mm) == len(states)
    assert np.allclose(breached.medial_wall_mm, [state["bone_left_mm"] for state in states], rtol=0, atol=1e-9)
    assert metrics(breached)["medial_wall_remaining_mm"] == 0.0
    event = next(e for e in breached.events if e["kind"] == "medial_wall_breached")
    assert event["face"] == MEDIAL_WALL


def test_an_undone_breach_leaves_the_bone_it_undid_and_still_scores(session):
    states, _, path = session
    record = read_reaming(read_session(path).groups["reaming"])
    found = metrics(record)
    # the final bone is the one reamed after the undo: the least bone left over its frames, the same as the live figure then
    assert len(states) > FRAMES_AFTER_UNDO and np.array_equal(record.frame[-FRAMES_AFTER_UNDO:], np.arange(1, FRAMES_AFTER_UNDO + 1))
    kept = record.medial_wall_mm[-FRAMES_AFTER_UNDO:]
    assert found["medial_wall_remaining_mm"] == pytest.approx(kept.min()) and kept.min() > 0.0
    assert kept == pytest.approx([state["bone_left_mm"] for state in states[:FRAMES_AFTER_UNDO]])  # the same inputs, the same bone
    criterion = next(c for c in criteria(record) if c.name == "no perforation or breach")
    assert criterion.points == 0 and "medial wall breached" in criterion.measured
    page = build_report(path)
    assert f"<td>{found['medial_wall_remaining_mm']:.1f} mm</td>" in page and "undo" in page
