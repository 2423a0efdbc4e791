"""A killed ``thrsim serve`` loses at most the last second of a session: the journal holds the
inputs up to the kill, and the next start closes the session as interrupted, which ``thrsim
report`` and ``thrsim replay`` then read like any other."""

from __future__ import annotations

import json
import socket
import time
import urllib.request

import pytest
from app_helpers import ServedTrainer, next_of_type, read_message, reamer_to_reference
from checkout_cli import run_thrsim
from websockets.sync.client import connect

from thrsim.app.modes import MODES
from thrsim.app.navigation import NavigationTrainer
from thrsim.io import igtl
from thrsim.session import read_session
from thrsim.session.journal import Journal


@pytest.mark.timeout(600)  # two servers, a reaming session relived at the restart, two replays
def test_a_killed_server_keeps_the_session_in_its_journal_and_closes_it_as_interrupted_at_the_next_start(tmp_path):
    served = ServedTrainer(tmp_path)
    targets = NavigationTrainer(side="right").targets
    acked, sent_poses = [], []
    try:
        with (
            connect(f"ws://127.0.0.1:{served.port}/ws/navigation", open_timeout=10) as ws,
            connect(f"ws://127.0.0.1:{served.port}/ws/reaming", open_timeout=10) as reaming,
            socket.create_connection(("127.0.0.1", served.igtl_port), timeout=5) as tracker,
        ):
            session_id = next_of_type(ws, "hello")["session"]
            reaming_id = next_of_type(reaming, "hello")["session"]
            reaming.send(json.dumps({"type": "run", "action": "start"}))
            assert next_of_type(reaming, "ack")["message"] == "reaming"
            deadline = time.monotonic() + 3.0
            k = 0
            while time.monotonic() < deadline:
                inclination = 30.0 + 0.25 * k
                ws.send(json.dumps({"type": "reamer", "inclination_deg": inclination, "anteversion_deg": 15}))
                assert next_of_type(ws, "ack")["message"] == "reamer steered"
                acked.append(inclination)
                if k % 3 == 0:
                    pose = reamer_to_reference(targets, 35.0 + 0.1 * k, 20.0)
                    tracker.sendall(igtl.encode_message(igtl.Message("TRANSFORM", "ReamerToReference", igtl.pack_transform(pose))))
                    read_message(tracker)
                    sent_poses.append(time.monotonic())
                k += 1
                time.sleep(0.03)
            last_state = next_of_type(ws, "state")
            seen = time.monotonic()
            served.process.kill()  # SIGKILL: nothing of the server's shutdown runs
            killed = time.monotonic()
            served.process.wait(10)
    finally:
        served.stop()
    assert killed - seen < 1.0

    journal = Journal(tmp_path / f"{session_id}.journal")
    inputs = list(journal.inputs())
    controls = [payload["inclination_deg"] for kind, _, payload in inputs if kind == "control"]
    assert controls == acked  # every control the server acknowledged is on disk
    poses = [time_s for kind, time_s, _ in inputs if kind == "pose"]
    assert len(poses) >= sum(sent < killed - 1.0 for sent in sent_poses)  # every tracker pose older than a second
    assert inputs[-1][1] >= last_state["session"]["elapsed_s"]  # the journal reaches the last state the page saw
    assert not (tmp_path / f"{session_id}.h5").exists()

    restarted = ServedTrainer(tmp_path)
    try:
        with urllib.request.urlopen(restarted.url + "/api/sessions", timeout=10) as response:
            listed = {entry["id"]: entry for entry in json.loads(response.read())["sessions"]}
        assert listed[session_id]["interrupted"] and listed[reaming_id]["interrupted"]
    finally:
        assert restarted.stop() == 0
    assert restarted.stderr().count("interrupted session closed") == 2  # the server's log says what it closed
    assert sorted(p.name for p in tmp_path.glob("*.journal")) == []  # both closed, and the restarted server's idle sessions left none
    session = read_session(tmp_path / f"{session_id}.h5")
    assert session.attrs["interrupted"] and session.inputs.count == len(inputs)
    reamed = MODES["reaming"].read_record(read_session(tmp_path / f"{reaming_id}.h5").groups["reaming"])
    assert len(reamed.removed) > 0  # the frames reamed before the kill, rebuilt from the journal

    for name in (session_id, reaming_id):
        path = tmp_path / f"{name}.h5"
        report = run_thrsim("report", str(path), "--out", str(tmp_path / f"{name}.html"))
        assert report.returncode == 0, report.stderr
        assert "interrupted" in (tmp_path / f"{name}.html").read_text()
        replay = run_thrsim("replay", str(path), "--json", timeout=300)
        assert replay.returncode == 0, replay.stderr
        assert json.loads(replay.stdout)["reproduced"]
