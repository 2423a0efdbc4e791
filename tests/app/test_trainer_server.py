"""``thrsim serve`` as a user runs it: a child process on free 127.0.0.1 ports, real HTTP,
WebSocket and OpenIGTLink clients; bad input refused with a message; sessions never lost."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.error
import urllib.request

import pytest
from app_helpers import (
    REPO,
    ServedTrainer,
    checkout_env,
    next_of_type,
    reamer_to_reference,
    send_transform,
    wait_for,
)
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from thrsim.app.navigation import NavigationTrainer
from thrsim.session import read_session


def get(url: str, headers: dict | None = None, timeout: float = 10.0) -> tuple[int, str, dict]:
    request = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=timeout) as response:
            return response.status, response.read().decode(), dict(response.headers)
    except urllib.error.HTTPError as error:
        return error.code, error.read().decode(), dict(error.headers)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    trainer = ServedTrainer(tmp_path_factory.mktemp("sessions"))
    yield trainer
    trainer.stop()


def ws_url(served: ServedTrainer) -> str:
    return f"ws://127.0.0.1:{served.port}/ws/navigation"


def test_page_and_three_js_are_served_locally(served):
    status, html, _ = get(served.url + "/")
    assert status == 200 and '"three": "/vendor/three/build/three.module.js"' in html
    assert "https://" not in html and "three.js is not installed" not in html
    status, module, _ = get(served.url + "/vendor/three/build/three.module.js")
    assert status == 200 and "./three.core.js" in module  # why the page needs an import map
    assert get(served.url + "/vendor/three/build/three.core.js")[0] == 200
    assert get(served.url + "/static/navigation.js")[0] == 200
    assert json.loads(get(served.url + "/api/modes")[1])["modes"][0]["path"] == "/"


def test_state_stream_rate_and_bad_messages_refused_without_dropping_the_connection(served):
    with connect(ws_url(served), open_timeout=10) as ws:
        hello = next_of_type(ws, "hello")
        assert len(hello["scene"]["landmarks"]) == 27 and hello["igtl"][1] == served.igtl_port
        first = next_of_type(ws, "state")
        for bad in ("{oops", '{"type": "reamer", "inclination_deg": 91, "anteversion_deg": 0}', '{"type": "nuke"}', "[]"):
            ws.send(bad)
            assert next_of_type(ws, "error")["message"]
        ws.send(b"\x00\x01binary")
        assert "binary" in next_of_type(ws, "error")["message"]
        ws.send(json.dumps({"type": "reamer", "inclination_deg": 40, "anteversion_deg": 15}))
        assert next_of_type(ws, "ack")["message"] == "reamer steered"
        states = [next_of_type(ws, "state") for _ in range(60)]
        assert states[-1]["zone"]["colour"] == "green"
        # States keep flowing at the tick: more than 30 per second of session time.
        span = states[-1]["session"]["elapsed_s"] - first["session"]["elapsed_s"]
        assert states[-1]["session"]["elapsed_s"] > first["session"]["elapsed_s"]
        assert len(states) / span > 30 or span < 2.0
    assert json.loads(get(served.url + "/api/health")[1])["ok"]


def test_openigtlink_transform_moves_the_reamer_in_the_stream(served):
    targets = NavigationTrainer(side="right").targets
    pose = reamer_to_reference(targets, 30.0, 25.0)
    with connect(ws_url(served), open_timeout=10) as ws:
        next_of_type(ws, "state")
        reply = send_transform(served.igtl_port, "ReamerToReference", pose, count=3, interval_s=0.02)
        assert reply.type_name == "STRING" and reply.device_name == "NavigationState"
        for _ in range(300):
            state = next_of_type(ws, "state")
            if state["tools"]["Reamer"]["source"] == "tracker":
                break
        assert state["tools"]["Reamer"]["source"] == "tracker"
        assert state["angles"]["radiographic"] == pytest.approx([30.0, 25.0], abs=0.01)
        assert state["zone"]["colour"] == "amber"


def test_ending_a_session_saves_it_and_serves_its_report(served):
    with connect(ws_url(served), open_timeout=10) as ws:
        session_id = next_of_type(ws, "hello")["session"]
        ws.send(json.dumps({"type": "probe", "action": "touch"}))
        next_of_type(ws, "ack")
        time.sleep(0.8)
        ws.send(json.dumps({"type": "end_session"}))
        saved = next_of_type(ws, "session_saved")
        assert saved["session"] == session_id
        fresh = next_of_type(ws, "hello")
        assert fresh["session"] != session_id
    path = served.sessions / f"{session_id}.h5"
    session = read_session(path)
    assert [json.loads(m)["type"] for _, _, m in session.inputs.controls][-2:] == ["probe", "end_session"]
    status, html, headers = get(served.url + saved["report"])
    assert status == 200 and "Assessment report" in html and "data:image/png;base64," in html
    assert get(served.url + "/sessions/..%2F..%2Fetc/report")[0] == 404
    assert session_id in get(served.url + "/api/sessions")[1]


def test_token_guards_every_request_and_socket(tmp_path):
    served = ServedTrainer(tmp_path, "--token", "s3cret-token")
    try:
        assert get(served.url + "/")[0] == 401
        assert get(served.url + "/static/navigation.js")[0] == 401
        assert get(served.url + "/?token=wrong-token")[0] == 401
        status, _, headers = get(served.url + "/?token=s3cret-token")
        assert status == 200 and "thrsim_token=s3cret-token" in headers.get("set-cookie", "")
        assert get(served.url + "/vendor/three/build/three.module.js", {"Cookie": "thrsim_token=s3cret-token"})[0] == 200
        assert get(served.url + "/api/health", {"Authorization": "Bearer s3cret-token"})[0] == 200
        with pytest.raises(InvalidStatus):
            connect(ws_url(served), open_timeout=10)
        with connect(ws_url(served) + "?token=s3cret-token", open_timeout=10) as ws:
            assert next_of_type(ws, "hello")["mode"] == "navigation"
        with pytest.raises(InvalidStatus):  # another site's page may not drive the trainer
            connect(ws_url(served) + "?token=s3cret-token", open_timeout=10, origin="http://evil.example")
    finally:
        assert served.stop() == 0


def test_stopping_the_server_saves_the_live_session(tmp_path):
    served = ServedTrainer(tmp_path)
    with connect(ws_url(served), open_timeout=10) as ws:
        session_id = next_of_type(ws, "hello")["session"]
        ws.send(json.dumps({"type": "reamer", "inclination_deg": 42, "anteversion_deg": 12}))
        next_of_type(ws, "ack")
    assert served.stop() == 0
    assert wait_for(lambda: (tmp_path / f"{session_id}.h5").is_file(), timeout=5)
    assert read_session(tmp_path / f"{session_id}.h5").inputs.controls


@pytest.mark.parametrize(
    "args, message",
    [
        (["--host", "0.0.0.0"], "access token"),
        (["--sessions", "/nonexistent/deeper/sessions"], "cannot create sessions folder"),
    ],
)
def test_serve_refuses_bad_options_in_one_line(tmp_path, args, message):
    done = subprocess.run(
        [sys.executable, "-m", "thrsim", "serve", "--port", "0", "--igtl-port", "0", "--sessions", str(tmp_path), *args],
        cwd=REPO, capture_output=True, text=True, timeout=60, env=checkout_env(),
    )  # fmt: skip
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and message in done.stderr


def test_serve_refuses_a_taken_port(served, tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "thrsim", "serve", "--port", str(served.port), "--igtl-port", "0", "--sessions", str(tmp_path)],
        cwd=REPO, capture_output=True, text=True, timeout=60, env=checkout_env(),
    )  # fmt: skip
    assert done.returncode == 2 and "cannot listen" in done.stderr and done.stderr.count("\n") == 1
    assert get(served.url + "/api/health")[0] == 200  # the running trainer is untouched
