"""The edge of the modelled bone on a real whole-socket session: the shipped socket model on the
native 46 mm socket meshed coarse, the 52 mm reamer pushed at 400 N at the safe zone's centre,
which breaks through the socket's supported boundary (where the modelled bone is cut off, not
anatomy) with the medial wall still far. Every state's bone left before that edge is checked
against the test's own reading of the socket's mesh; the warning's event comes once per reamer
before the break, and the break is named, in the event and the report, as the modelled bone ending."""

from __future__ import annotations

import numpy as np
import pytest
from app_helpers import SocketSession, own_bone_left

from thrsim.app.reaming import BREAK_WARNING_MM, socket_in_patch
from thrsim.geometry.mesh import SUPPORTED
from thrsim.report import build_report
from thrsim.report.reaming import criteria
from thrsim.session.file import read_session
from thrsim.session.reaming import CUT_EDGE, read_reaming

pytestmark = pytest.mark.timeout(900)

ELEMENT_MM = 5.0  # coarse: the edge's arithmetic, not the mesh's resolution, is under test
REAMER_MM, PUSH_N = 52, 400.0


def _ream_until_it_stops(session: SocketSession, mesh, frames: int = 120) -> list[dict]:
    """Ream until the simulator pauses (at most ``frames`` ticks); each state with the test's own edge figure
    (the elements whose loss is a perforation: those with a node on the supported boundary, all their nodes)."""
    edge_left = own_bone_left(mesh, SUPPORTED)
    states = []
    for _ in range(frames):
        state = session.tick()
        if session.live.trainer._reamer_position is not None:
            states.append({**state, "own_edge_left_mm": edge_left(session.live.trainer, REAMER_MM / 2e3)})
        if not state["running"]:
            break
    return states


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    folder = tmp_path_factory.mktemp("socket-edge")
    mesh = socket_in_patch(46.0, ELEMENT_MM)  # the same socket meshed again, independently of the trainer
    scripted = SocketSession(folder, ELEMENT_MM)
    scripted.send(type="force", newton=PUSH_N)
    scripted.send(type="reamer_size", size_mm=REAMER_MM)
    scripted.send(type="run", action="start")
    first = _ream_until_it_stops(scripted, mesh)
    scripted.send(type="run", action="undo")
    scripted.send(type="run", action="start")
    again = _ream_until_it_stops(scripted, mesh)
    return first, again, scripted.live.trainer.scene(), scripted.live.save(folder)


def test_the_state_gives_the_bone_left_before_the_modelled_bones_edge(session):
    first, again, scene, _ = session
    assert scene["reaming"]["bone"] == "socket" and scene["reaming"]["warning_mm"] == BREAK_WARNING_MM
    assert len(first) > 3
    for state in first + again:
        assert state["edge_left_mm"] == pytest.approx(state["own_edge_left_mm"], abs=1e-9)
    left = [state["edge_left_mm"] for state in first]
    assert left[0] > BREAK_WARNING_MM and left[-1] == 0.0 and np.all(np.diff(left) <= 1e-9)  # the reamer only goes in
    # the edge, not the medial wall, stopped it: the medial wall's bone was never under the warning
    assert min(state["bone_left_mm"] for state in first) > 2 * BREAK_WARNING_MM


def test_the_warning_is_an_event_once_per_reamer_before_the_break(session):
    first, again, _, _ = session
    for states in (first, again):  # the undo took the reamer back: the warning shows again, and so is said again
        kinds = [event["kind"] for state in states for event in state["events"]]
        assert kinds.count("edge_warning") == 1 and kinds.index("edge_warning") < kinds.index("perforated")
        at = next(k for k, state in enumerate(states) if any(event["kind"] == "edge_warning" for event in state["events"]))
        warned = next(event for event in states[at]["events"] if event["kind"] == "edge_warning")
        assert warned["edge_left_mm"] == states[at]["edge_left_mm"] < BREAK_WARNING_MM <= states[at - 1]["edge_left_mm"]
        assert warned["reamer_mm"] == REAMER_MM
        broken = next(event for state in states for event in state["events"] if event["kind"] == "perforated")
        assert broken["face"] == CUT_EDGE and "edge of the modelled bone" in broken["detail"]
        assert broken["medial_wall_left_mm"] == pytest.approx(states[-1]["bone_left_mm"]) and broken["medial_wall_left_mm"] > 1.0


def test_the_session_file_and_the_report_name_the_break_as_the_modelled_bone_ending(session):
    _, _, _, path = session
    record = read_reaming(read_session(path).groups["reaming"])
    kinds = [event["kind"] for event in record.events]
    assert kinds.count("edge_warning") == 2 and kinds.count("perforated") == 2
    assert all(event["face"] == CUT_EDGE for event in record.events if event["kind"] == "perforated")
    criterion = next(c for c in criteria(record) if c.name == "no perforation or breach")
    assert criterion.points == 0 and criterion.measured.startswith("through the edge of the modelled bone")
    assert "not at the medial wall" in criterion.measured and "medial wall breached" not in criterion.measured
    page = build_report(path)
    assert "perforated: the edge of the modelled bone" in page and "edge warning" in page
