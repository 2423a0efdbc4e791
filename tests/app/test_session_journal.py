"""The session journal: inputs on disk as they arrive, read back exactly, a torn tail cut off, and
the sessions a crash left open closed as interrupted, with every input the journal kept."""

from __future__ import annotations

import errno
import os
import time
import tracemalloc

import h5py
import numpy as np
import pytest

from thrsim.app.live import LiveSession, close_interrupted
from thrsim.app.modes import MODES
from thrsim.app.replay import replay_session
from thrsim.errors import ThrsimInputError
from thrsim.session import read_session
from thrsim.session.journal import Journal, JournalWriter, claimed

ATTRS = {"session_id": "20250101T000000Z-abcdef", "mode": "navigation", "started_utc": "2025-01-01T00:00:00+00:00"}


def _filled(path, sync_interval_s: float = 0.5) -> tuple[JournalWriter, np.ndarray]:
    journal = JournalWriter(path, ATTRS, sync_interval_s=sync_interval_s)
    pose = np.arange(16, dtype=float).reshape(4, 4) / 7.0
    journal.tick(0.0)
    journal.control(0.01, {"type": "probe", "action": "touch"})
    journal.pose(0.02, "ReamerToReference", pose)
    journal.force(0.03, 212.5)
    journal.tick(1 / 60)
    return journal, pose


def test_appended_inputs_read_back_in_order_and_exactly_while_the_journal_is_open(tmp_path):
    journal, pose = _filled(tmp_path / "s.journal")
    read = Journal(tmp_path / "s.journal")  # another reader, the writer still open: every record already reached the OS
    assert read.attrs == ATTRS
    inputs = list(read.inputs())
    assert [(kind, time_s) for kind, time_s, _ in inputs] == [
        ("tick", 0.0),
        ("control", 0.01),
        ("pose", 0.02),
        ("force", 0.03),
        ("tick", 1 / 60),
    ]
    assert inputs[1][2] == {"type": "probe", "action": "touch"}
    assert inputs[2][2][0] == "ReamerToReference" and np.array_equal(inputs[2][2][1], pose)
    assert inputs[3][2] == 212.5 and not read.torn
    assert (journal.count, journal.ticks) == (5, 2)
    with claimed(journal.path) as ours:
        assert not ours  # a live session holds it
    journal.close()
    with claimed(journal.path) as ours:
        assert ours


def test_the_journal_is_synced_to_disk_at_least_every_interval(tmp_path, monkeypatch):
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr("thrsim.session.journal.os.fsync", lambda fd: (synced.append(time.monotonic()), real_fsync(fd)))
    journal, _ = _filled(tmp_path / "s.journal", sync_interval_s=0.2)
    before = len(synced)
    journal.tick(0.5)
    time.sleep(0.6)
    assert len(synced) > before  # the syncer caught the appends within the interval
    idle = len(synced)
    time.sleep(0.5)
    assert len(synced) == idle  # nothing new appended: no needless syncs
    journal.close(remove=True)
    assert not journal.path.exists()


def test_a_torn_last_record_is_cut_off_and_everything_before_it_kept(tmp_path):
    path = tmp_path / "s.journal"
    journal, _ = _filled(path)
    journal.close()
    whole = path.read_bytes()
    for cut in (1, 5, 9):  # inside the last record's body, its CRC, its length
        path.write_bytes(whole[:-cut])
        read = Journal(path)
        kinds = [kind for kind, _, _ in read.inputs()]
        assert kinds == ["tick", "control", "pose", "force"] and read.torn
    garbled = bytearray(whole)
    garbled[-30] ^= 0xFF  # inside the force record: its CRC fails, the reading stops before it
    path.write_bytes(bytes(garbled))
    read = Journal(path)
    assert [kind for kind, _, _ in read.inputs()] == ["tick", "control", "pose"] and read.torn
    path.write_bytes(whole + b"\xff\xff\xff\x7f" + bytes(64))  # a garbled length: no 2 GiB read, the end of the journal
    read = Journal(path)
    assert len(list(read.inputs())) == 5 and read.torn
    path.write_bytes(whole[:20])  # cut inside the header
    with pytest.raises(ThrsimInputError, match="not a thrsim session journal"):
        Journal(path)


def test_a_long_pose_device_name_is_refused_before_it_is_logged(tmp_path):
    journal = JournalWriter(tmp_path / "s.journal", ATTRS)
    with pytest.raises(ThrsimInputError, match="more than 20"):
        journal.pose(0.0, "D" * 21, np.eye(4))
    assert journal.count == 0
    journal.close()


def test_records_the_disk_refuses_wait_in_memory_and_reach_the_file_in_order(tmp_path, monkeypatch, caplog):
    journal, _ = _filled(tmp_path / "s.journal")
    real_write = os.write
    full = [True]

    def write(fd, data):
        if full[0] and fd == journal._fd:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr("thrsim.session.journal.os.write", write)
    for k in range(3):
        journal.tick(1.0 + k)
    with pytest.raises(OSError):
        journal.flush()  # what a save does first: it cannot save while the journal is behind
    assert caplog.text.count("cannot write the session journal") == 1  # one line, not one a record
    full[0] = False
    journal.tick(4.0)
    times = [time_s for kind, time_s, _ in Journal(journal.path).inputs() if kind == "tick"]
    assert times == [0.0, 1 / 60, 1.0, 2.0, 3.0, 4.0] and "writes again" in caplog.text
    journal.close()


def test_a_long_session_keeps_its_inputs_on_disk_not_in_memory(tmp_path):
    session, now = _live(tmp_path, seed=1)
    pose = session.trainer.tools["Reamer"].pose.copy()
    session.tick()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for k in range(10_000):
            now[0] = k / 240  # a tracker at 240 Hz
            session.pose("ReamerToReference", pose, now[0])
            if k % 1000 == 999:
                session.tick()  # the queued poses are logged and applied
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < 300_000  # about 100 kB of numpy caches; 10,000 poses were 1.5 MB in memory before the journal
    started = time.perf_counter()
    path = session.save()
    assert time.perf_counter() - started < 5.0
    with h5py.File(path) as h5:
        matrix = h5["inputs/poses/matrix"]
        assert matrix.shape == (10_000, 4, 4) and matrix.compression == "gzip"
        assert h5["inputs/poses/device"][-1] == b"ReamerToReference"
    assert path.stat().st_size < 500_000  # the same pose 10,000 times: compressed, not 10,000 strings


def _live(folder, seed: int) -> tuple[LiveSession, list[float]]:
    now = [0.0]
    session = LiveSession(MODES["navigation"], {"side": "right", "seed": seed}, lambda: now[0], folder)
    return session, now


def test_a_session_that_never_ended_is_closed_as_interrupted_with_its_inputs(tmp_path):
    session, now = _live(tmp_path, seed=5)
    for k in range(90):
        now[0] += 1 / 60
        if k % 15 == 0:
            session.control({"type": "probe", "action": "touch"})
        if k == 40:
            session.pose("ReamerToReference", session.trainer.tools["Reamer"].pose, now[0])
        session.tick()
    live_record = session.trainer.record()
    assert close_interrupted(tmp_path) == []  # the live session holds its journal
    quiet, _ = _live(tmp_path, seed=6)
    quiet.tick()
    saved, _ = _live(tmp_path, seed=7)
    saved.control({"type": "probe", "action": "touch"})
    saved_path = saved.save()
    stale = tmp_path / f"{saved.id}.journal"
    stale.write_bytes((tmp_path / f"{session.id}.journal").read_bytes())  # saved, then the crash before its journal went
    for dead in (session, quiet):
        dead.journal._closing.set()  # as a killed process: the journal is left as it is, its lock dropped
        os.close(dead.journal._fd)

    closed = close_interrupted(tmp_path)

    target = tmp_path / f"{session.id}.h5"
    assert closed == [target]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([target.name, saved_path.name])  # every journal gone
    recovered = read_session(target)
    assert recovered.attrs["interrupted"] and not read_session(saved_path).attrs["interrupted"]
    assert recovered.attrs["duration_s"] == pytest.approx(1.5)
    assert recovered.inputs.count == 90 + 6 + 1 and recovered.inputs.pose_devices() == ["ReamerToReference"]
    record = MODES["navigation"].read_record(recovered.groups["navigation"])
    assert np.array_equal(record.angles, live_record.angles, equal_nan=True) and record.events == live_record.events
    assert replay_session(target).reproduced
