"""The reaming mode of ``thrsim serve`` end to end: a real server process with the shipped
model, WebSocket and OpenIGTLink clients on 127.0.0.1; the bone arrives as binary frames of what
changed, exact for every viewer; sessions are saved with their reaming group."""

from __future__ import annotations

import json
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from app_helpers import ServedTrainer, next_of_type, send_force, wait_for
from websockets.sync.client import connect

from thrsim.app.bone_stream import MESH_MAGIC, apply
from thrsim.learn.model_dir import load_model
from thrsim.session import read_session

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    trainer = ServedTrainer(tmp_path_factory.mktemp("sessions"))  # the shipped model
    yield trainer
    trainer.stop()


def ws_url(served: ServedTrainer) -> str:
    return f"ws://127.0.0.1:{served.port}/ws/reaming"


def collect(ws, seconds: float, levels: np.ndarray | None, until=None) -> tuple[np.ndarray | None, dict | None, list[int]]:
    """Receive for ``seconds`` (or, with ``until``, until a state satisfies it, within 60 s): the bone
    as decoded from the binary frames, the last state, frame sizes."""
    deadline = time.monotonic() + (60.0 if until else seconds)
    state, sizes = None, []
    while time.monotonic() < deadline and not (until and state and until(state)):
        raw = ws.recv(timeout=5)
        if isinstance(raw, bytes):
            _, levels = apply(raw, levels)
            sizes.append(len(raw))
        else:
            message = json.loads(raw)
            if message["type"] == "state":
                state = message
    return levels, state, sizes


def until_ack(ws, levels: np.ndarray) -> np.ndarray:
    """Receive up to the next ack, applying the bone frames on the way (none may be skipped)."""
    while True:
        raw = ws.recv(timeout=5)
        if isinstance(raw, bytes):
            _, levels = apply(raw, levels)
        elif json.loads(raw)["type"] == "ack":
            return levels


def test_the_page_and_the_mesh_are_served(served):
    with urllib.request.urlopen(served.url + "/reaming", timeout=10) as response:
        html = response.read().decode()
    assert "/static/reaming.js" in html and "https://" not in html
    for asset in ("/static/reaming.js", "/static/bone.js"):
        with urllib.request.urlopen(served.url + asset, timeout=10) as response:
            assert response.status == 200
    with urllib.request.urlopen(served.url + "/api/reaming/mesh", timeout=10) as response:
        payload = response.read()
    model = load_model()
    assert payload[:4] == MESH_MAGIC
    nodes, tets = np.frombuffer(payload[8:16], dtype="<u4")
    assert (nodes, tets) == (model.mesh.n_nodes, model.mesh.n_tets)
    materials_end = 16 + 12 * nodes + 33 * tets  # nodes, tets, neighbours, one material byte each
    (names_length,) = np.frombuffer(payload[materials_end : materials_end + 4], dtype="<u4")
    assert len(payload) == materials_end + 4 + names_length
    assert json.loads(payload[materials_end + 4 :]) == list(model.mesh.material_names) == ["cortical"]  # the patch: one layer
    assert not payload[16 + 12 * nodes + 32 * tets : materials_end].strip(b"\0")  # every element the first material


def test_reaming_streams_what_changed_and_every_viewer_ends_up_exact(served):
    with connect(ws_url(served), open_timeout=10) as first:
        hello = next_of_type(first, "hello")
        with connect(f"{ws_url(served)}?observe={hello['session']}", open_timeout=10) as second:  # an instructor watching
            elements = load_model().mesh.n_tets
            assert hello["scene"]["reaming"]["available"] and hello["scene"]["reaming"]["elements"] == elements
            first.send(json.dumps({"type": "reamer", "inclination_deg": 45, "anteversion_deg": 20}))
            first.send(json.dumps({"type": "run", "action": "start"}))
            levels_first, state, sizes = collect(first, 0, None, until=lambda state: state["reaming"]["frame"] > 20)
            assert state["reaming"]["running"] and state["reaming"]["frame"] > 20
            assert sizes and sizes[0] < elements // 4  # a compressed keyframe on connect
            assert np.mean(sizes[1:]) < 0.05 * 4 * elements  # deltas: under 5 % of every element as float32
            removed = int(np.sum(levels_first == 0))
            assert removed > 0
            first.send(json.dumps({"type": "run", "action": "pause"}))
            levels_first = until_ack(first, levels_first)
            time.sleep(0.3)
            levels_first, state, _ = collect(first, 0.5, levels_first)
            # the second viewer read nothing for 2 s: it still ends up with the same bone
            levels_second, _, _ = collect(second, 1.0, None)
            assert np.array_equal(levels_first, levels_second)
            assert int(np.sum(levels_first == 0)) == state["reaming"]["removed"]
            first.send(json.dumps({"type": "run", "action": "reset"}))
            levels_first = until_ack(first, levels_first)
            time.sleep(0.3)
            levels_first, state, _ = collect(first, 0.5, levels_first)
            assert state["reaming"]["removed"] == 0 and not np.any(levels_first == 0)


def test_a_force_sensor_drives_the_push_and_the_session_keeps_the_reaming(served):
    with connect(ws_url(served), open_timeout=10) as ws:
        next_of_type(ws, "hello")
        ws.send(json.dumps({"type": "force", "newton": 120}))
        assert next_of_type(ws, "ack")["message"] == "push 120 N"
        ws.send(json.dumps({"type": "force", "newton": 900}))
        assert "newton" in next_of_type(ws, "error")["message"]
        ws.send(json.dumps({"type": "run", "action": "start"}))
        send_force(served.igtl_port, 310.0)
        assert wait_for(lambda: next_of_type(ws, "state")["reaming"]["force_source"] == "sensor", timeout=5)
        assert wait_for(lambda: next_of_type(ws, "state")["reaming"]["force_n"] == 120, timeout=5)
        assert wait_for(lambda: next_of_type(ws, "state")["reaming"]["frame"] > 10, timeout=30)  # this page's own session
        ws.send(json.dumps({"type": "end_session"}))
        saved = next_of_type(ws, "session_saved")
    session = read_session(saved["file"])
    assert session.settings["mode"] == "reaming"
    reaming = session.groups["reaming"]
    forces = np.asarray(reaming["trace"]["force_n"])
    assert len(forces) > 10 and 310.0 in forces and 120.0 in forces
    assert len(reaming["final_alpha"]) == load_model().mesh.n_tets


def test_without_a_usable_model_reaming_says_why_and_navigation_serves(tmp_path):
    import subprocess
    import sys
    import urllib.error

    from app_helpers import REPO, checkout_env

    missing = subprocess.run(
        [sys.executable, "-m", "thrsim", "serve", "--model", str(tmp_path / "missing"), "--sessions", str(tmp_path)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        env=checkout_env(),
    )
    assert missing.returncode == 2 and "no such model folder" in missing.stderr and missing.stderr.count("\n") == 1
    empty = tmp_path / "not-a-model"
    empty.mkdir()
    server = ServedTrainer(tmp_path, "--model", str(empty))
    try:
        with connect(ws_url(server), open_timeout=10) as ws:
            reaming = next_of_type(ws, "hello")["scene"]["reaming"]
            assert not reaming["available"] and "not a thrsim model directory" in reaming["unavailable"]
            ws.send(json.dumps({"type": "run", "action": "start"}))
            assert "unavailable" in next_of_type(ws, "error")["message"]
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(server.url + "/api/reaming/mesh", timeout=10)
        assert refused.value.code == 404
        with connect(f"ws://127.0.0.1:{server.port}/ws/navigation", open_timeout=10) as ws:
            assert len(next_of_type(ws, "hello")["scene"]["landmarks"]) == 27
    finally:
        server.stop()


@pytest.mark.timeout(600)  # compiling at start: tens of seconds on a cold cache
def test_served_as_users_run_it_the_network_is_compiled_and_the_session_replays_exactly(tmp_path):
    import subprocess
    import sys

    from app_helpers import REPO, checkout_env

    server = ServedTrainer(tmp_path, compile=True, timeout=300)
    try:
        health = json.loads(urllib.request.urlopen(server.url + "/api/health", timeout=10).read())
        assert health["reaming_network"] == {"state": "compiled", "compile_error": None}
        # sessions ended one after another, as the end limit's burst allows: each end starts the next
        # session on a worker thread while the ticker steps (the two once shared the model graph's
        # scratch, and the server crashed within a few ends)
        ended = []
        for _ in range(5):
            with connect(ws_url(server), open_timeout=10) as ws:
                next_of_type(ws, "hello")
                ws.send(json.dumps({"type": "run", "action": "start"}))
                assert wait_for(lambda ws=ws: next_of_type(ws, "state")["reaming"]["removed"] > 0, timeout=60)
                ws.send(json.dumps({"type": "end_session"}))
                ended.append(next_of_type(ws, "session_saved"))
        saved = ended[0]
        assert len({end["session"] for end in ended}) == 5 and all(Path(end["file"]).is_file() for end in ended)
    except Exception as error:  # say how the server ended (a crash once closed the socket unannounced)
        code = server.stop()
        raise AssertionError(f"served trainer: exit code {code}, stderr:\n{server.stderr()[-3000:]}") from error
    assert server.stop() == 0, server.stderr()[-3000:]
    assert read_session(saved["file"]).settings["compile"] is True
    replay = subprocess.run(
        [sys.executable, "-m", "thrsim", "replay", saved["file"], "--json"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
        env=checkout_env(),
    )
    assert replay.returncode == 0, replay.stderr
    assert json.loads(replay.stdout)["reproduced"] is True
