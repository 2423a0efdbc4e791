"""A live session's inputs: tracker poses and force readings never wait for a step in flight, and
land in the log and the trainer in arrival order, before the next step or control."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from thrsim.app.live import LiveSession
from thrsim.app.modes import MODES
from thrsim.session.journal import Journal


def _session(folder: Path) -> tuple[LiveSession, list[float]]:
    now = [0.0]
    return LiveSession(MODES["navigation"], {"side": "right", "seed": 1}, lambda: now[0], folder), now


def _logged(session: LiveSession) -> list[tuple[str, float, object]]:
    return list(Journal(session.journal.path).inputs())


def _reamer_pose(session: LiveSession) -> np.ndarray:
    pose = session.trainer.tools["Reamer"].pose.copy()
    pose[:3, 3] += 0.01
    return pose


def test_a_pose_arriving_during_a_step_returns_at_once_and_lands_before_the_next_step(tmp_path):
    session, now = _session(tmp_path)
    session.tick()
    pose = _reamer_pose(session)
    done = threading.Event()
    with session.lock:  # a step in flight, as the ticker's worker thread holds it
        worker = threading.Thread(target=lambda: (session.pose("ReamerToReference", pose, 0.5), session.force(120.0, 0.6), done.set()))
        worker.start()
        assert done.wait(5.0)  # did not wait for the lock
        assert session.journal.count == 1  # queued, not yet logged
    now[0] = 1.0
    session.tick()
    kinds = [(kind, time_s) for kind, time_s, _ in _logged(session)]
    assert kinds == [("tick", 0.0), ("pose", 0.5), ("force", 0.6), ("tick", 1.0)]
    assert session.trainer.force_n == 120.0


def test_a_control_applies_the_queued_readings_first_and_a_refused_pose_is_logged_and_skipped(tmp_path):
    session, now = _session(tmp_path)
    session.tick()
    before = session.trainer.tools["Reamer"].pose.copy()
    session.pose("ReamerToReference", np.full((4, 4), np.nan), 0.2)  # not a pose: refused when applied
    session.force(90.0, 0.3)
    now[0] = 0.4
    session.control({"type": "reamer", "inclination_deg": 42, "anteversion_deg": 18})
    assert [kind for kind, _, _ in _logged(session)] == ["tick", "pose", "force", "control"]
    assert session.trainer.force_n == 90.0  # the reading after the refused pose still landed
    assert not np.isnan(session.trainer.tools["Reamer"].pose).any() and not np.array_equal(session.trainer.tools["Reamer"].pose, before)


def test_each_state_carries_its_ticks_duration_and_the_sessions_worst(tmp_path):
    session, now = _session(tmp_path)
    ticks = []
    for k in range(5):
        now[0] = k / 60
        ticks.append(session.tick()["session"])
    assert all(tick["tick_ms"] > 0 for tick in ticks)
    worst = [tick["worst_tick_ms"] for tick in ticks]
    assert worst == list(np.maximum.accumulate([tick["tick_ms"] for tick in ticks]))  # the longest so far, never forgotten
    assert session.worst_tick_ms == worst[-1]
