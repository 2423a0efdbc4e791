"""``thrsim serve`` as a user runs it: a child process on free 127.0.0.1 ports, real HTTP,
WebSocket and OpenIGTLink clients; bad input refused with a message; sessions never lost."""

from __future__ import annotations

import asyncio
import json
import socket
import subprocess
import sys
import threading
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
from thrsim.app.server import NothingToSave, ServeSettings, SessionEndTooSoon, TrainerHub, create_app
from thrsim.config import SessionEndLimit
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


def test_each_page_gets_its_own_session_and_an_observer_watches_without_steering(served):
    with connect(ws_url(served), open_timeout=10) as trainee, connect(ws_url(served), open_timeout=10) as other:
        one, two = next_of_type(trainee, "hello"), next_of_type(other, "hello")
        assert one["session"] != two["session"] and one["role"] == two["role"] == "trainee"
        assert one["observe"] == f"/?observe={one['session']}"
        with connect(f"{ws_url(served)}?observe={one['session']}", open_timeout=10) as observer:
            hello = next_of_type(observer, "hello")
            assert hello["session"] == one["session"] and hello["role"] == "observer"
            observer.send(json.dumps({"type": "reamer", "inclination_deg": 30, "anteversion_deg": 25}))
            assert "observes session" in next_of_type(observer, "error")["message"]  # refused, not journaled
            trainee.send(json.dumps({"type": "reamer", "inclination_deg": 42, "anteversion_deg": 12}))
            assert wait_for(lambda: next_of_type(observer, "state")["angles"]["radiographic"][0] == pytest.approx(42.0, abs=0.01))
            assert next_of_type(other, "state")["angles"]["radiographic"][0] != pytest.approx(42.0, abs=0.01)  # the other trainee's own aim
            health = json.loads(get(served.url + "/api/health")[1])
            assert health["sessions"]["navigation"] >= 2 and health["viewers"]["navigation"] >= 3
            trainee.close()  # the trainee leaves: the observer is told, and its view closes
            assert next_of_type(observer, "session_over")["message"].startswith(f"the trainee left session {one['session']}")
    with connect(f"{ws_url(served)}?observe=20250101T000000Z-abcdef", open_timeout=10) as stray:
        assert "no live navigation session" in next_of_type(stray, "refused")["message"]
    assert not (served.sessions / f"{one['session']}.h5").exists()  # nothing assessed was done in it: not saved


def handshake_status(served: ServedTrainer, host: str, origin: str | None = None, path: str = "/ws/navigation") -> int:
    """The HTTP status a WebSocket handshake gets (101: opened) with this Host and Origin, on a raw socket."""
    lines = [f"GET {path} HTTP/1.1", f"Host: {host}", "Upgrade: websocket", "Connection: Upgrade"]
    lines += ["Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Version: 13"] + ([f"Origin: {origin}"] if origin else [])
    with socket.create_connection(("127.0.0.1", served.port), timeout=10) as sock:
        sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        return int(sock.recv(4096).split(b" ", 2)[1])


def test_on_loopback_only_loopback_host_names_are_answered(served):
    # DNS rebinding: a page of evil.example whose name now resolves to 127.0.0.1 sends Host: evil.example
    for path in ("/", "/api/sessions", "/api/health", "/sessions/20250101T000000Z-abcdef/file"):
        for host in ("evil.example", f"evil.example:{served.port}", "127.0.0.1.evil.example", "10.0.0.1"):
            status, body, _ = get(served.url + path, {"Host": host})
            assert status == 403 and "not one this trainer answers to" in body, (path, host)
    for host in ("localhost", f"localhost:{served.port}", f"127.0.0.1:{served.port}", "127.1.2.3", f"[::1]:{served.port}"):
        assert get(served.url + "/api/health", {"Host": host})[0] == 200, host
    evil = f"evil.example:{served.port}"
    assert handshake_status(served, evil, origin=f"http://{evil}") == 403  # matching Host and Origin: still refused
    assert handshake_status(served, f"localhost:{served.port}", origin=f"http://localhost:{served.port}") == 101
    assert handshake_status(served, f"localhost:{served.port}", origin="http://evil.example") == 403


def test_an_end_with_nothing_done_saves_nothing_and_ends_are_rate_limited(tmp_path):
    now = [0.0]
    hub = TrainerHub(ServeSettings(sessions_dir=tmp_path, igtl=False, compile=False), clock=lambda: now[0])
    seat = hub.open_seat("navigation", None)

    def acquire_a_landmark() -> None:
        seat.session.control({"type": "probe", "action": "touch"})
        for _ in range(45):  # held still for 0.75 s: acquired
            now[0] += 1 / 60
            hub.tick()

    first = seat.session
    with pytest.raises(NothingToSave, match="nothing to save"):  # a double click's second end, or an end before anything
        hub.end_asked(seat)
    assert seat.session is first and list(tmp_path.glob("*.h5")) == []  # the session goes on, no empty file scored 0
    burst = SessionEndLimit().burst
    for _ in range(burst):
        acquire_a_landmark()
        hub.end_asked(seat)
    acquire_a_landmark()
    with pytest.raises(SessionEndTooSoon, match="sessions ended too often"):
        hub.end_asked(seat)
    assert len(list(tmp_path.glob("*.h5"))) == burst
    assert hub.leave(seat, None) is not None and hub.seats == []  # the trainee leaving saves what was done
    assert len(list(tmp_path.glob("*.h5"))) == burst + 1


def test_ends_asked_while_the_ticker_steps_lose_no_trace_row(tmp_path, caplog):
    """An end asked during a step once read the record as the step appended to it: the step failed
    (an array exporting its buffer cannot grow) and the trace lost a row, which broke the report."""
    hub = TrainerHub(ServeSettings(sessions_dir=tmp_path, igtl=False, compile=False))
    seat = hub.open_seat("navigation", None)
    stop = threading.Event()

    def ticker() -> None:
        while not stop.is_set():
            hub.tick()

    thread = threading.Thread(target=ticker)
    thread.start()
    asked, started = 0, time.monotonic()
    # ask until many ends met many steps (before the fix: dozens of failed steps in 1.5 s); the time cap only stops a hang
    while (asked < 100 or hub.ticks < 10) and time.monotonic() - started < 120.0:
        with pytest.raises(NothingToSave):
            hub.end_asked(seat)
        asked += 1
    stop.set()
    thread.join()
    record = seat.session.trainer.record()
    assert asked >= 100 and hub.ticks >= 10
    assert not [r for r in caplog.records if "step failed" in r.getMessage()]
    assert len(record.time) == len(record.tool_codes) == len(record.phase) == len(record.angles) == hub.ticks


@pytest.mark.parametrize("source", ["environment", "file"])
def test_token_guards_every_request_and_socket(tmp_path, source):
    if source == "file":
        token_file = tmp_path / "token"
        token_file.write_text("s3cret-token\n")
        served = ServedTrainer(tmp_path, "--token-file", str(token_file))
    else:
        served = ServedTrainer(tmp_path, env={"THRSIM_TOKEN": "s3cret-token"})
    try:
        assert get(served.url + "/")[0] == 401
        assert get(served.url + "/static/navigation.js")[0] == 401
        assert get(served.url + "/?token=wrong-token")[0] == 401
        status, _, headers = get(served.url + "/?token=s3cret-token")
        assert status == 200 and "thrsim_token=s3cret-token" in headers.get("set-cookie", "")
        assert get(served.url + "/vendor/three/build/three.module.js", {"Cookie": "thrsim_token=s3cret-token"})[0] == 200
        assert get(served.url + "/api/health", {"Authorization": "Bearer s3cret-token"})[0] == 200
        assert get(served.url + "/api/health", {"Authorization": "Bearer s3cret-token", "Host": "evil.example"})[0] == 403
        with pytest.raises(InvalidStatus):
            connect(ws_url(served), open_timeout=10)
        with connect(ws_url(served) + "?token=s3cret-token", open_timeout=10) as ws:
            assert next_of_type(ws, "hello")["mode"] == "navigation"
        with pytest.raises(InvalidStatus):  # another site's page may not drive the trainer
            connect(ws_url(served) + "?token=s3cret-token", open_timeout=10, origin="http://evil.example")
    finally:
        assert served.stop() == 0
    assert "s3cret-token" not in " ".join(served.process.args)  # not on the command line, where ps shows it


def test_a_token_on_the_command_line_is_taken_with_a_warning(tmp_path):
    served = ServedTrainer(tmp_path, "--token", "s3cret-token")
    try:
        assert get(served.url + "/")[0] == 401 and get(served.url + "/?token=s3cret-token")[0] == 200
    finally:
        assert served.stop() == 0
    assert "--token shows the token to every user of this machine (ps)" in served.stderr()


def test_stopping_the_server_saves_the_live_session(tmp_path):
    served = ServedTrainer(tmp_path)
    with connect(ws_url(served), open_timeout=10) as ws:
        session_id = next_of_type(ws, "hello")["session"]
        ws.send(json.dumps({"type": "probe", "action": "touch"}))
        next_of_type(ws, "ack")
        time.sleep(0.8)  # a landmark acquired: a session worth saving
        assert served.stop() == 0
    assert wait_for(lambda: (tmp_path / f"{session_id}.h5").is_file(), timeout=5)
    assert read_session(tmp_path / f"{session_id}.h5").inputs.controls


@pytest.mark.parametrize(
    "args, message",
    [
        (["--host", "0.0.0.0"], "--host: 0.0.0.0 is reachable from other machines: give an access token (--token-file or THRSIM_TOKEN)"),
        (["--host", "0.0.0.0", "--token-file", "/nonexistent/token"], "cannot read the access token from /nonexistent/token"),
        (["--token", "s3cret-token", "--token-file", "/nonexistent/token"], "give the access token once"),
        (["--igtl-allow", "10.0.0.0/8"], "--igtl-host"),
        (["--igtl-host", "0.0.0.0"], "--igtl-allow"),
        (["--igtl-host", "0.0.0.0", "--igtl-allow", "10.0.0.0/33"], "--igtl-allow: 10.0.0.0/33: not an address or network"),
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


def test_serve_refuses_a_taken_haptic_port(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        done = subprocess.run(
            [sys.executable, "-m", "thrsim", "serve", "--port", "0", "--igtl-port", "0", "--sessions", str(tmp_path),
             "--haptic-port", str(taken.getsockname()[1])],
            cwd=REPO, capture_output=True, text=True, timeout=60, env=checkout_env(),
        )  # fmt: skip
    assert done.returncode == 2 and "cannot listen for the haptic stream on 127.0.0.1:" in done.stderr and done.stderr.count("\n") == 1


async def asgi_status(app, path: str, headers: dict[str, str]) -> int:
    """The status of a GET through the app in this process (no socket), with these headers."""
    scope = {
        "type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": "GET", "scheme": "http", "path": path,
        "raw_path": path.encode(), "root_path": "", "query_string": b"", "server": ("192.168.4.1", 8000), "client": ("192.168.4.9", 50000),
        "headers": [(name.lower().encode(), value.encode()) for name, value in headers.items()],
    }  # fmt: skip
    sent = []

    async def receive() -> dict:
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message: dict) -> None:
        sent.append(message)

    await app(scope, receive, send)
    return next(m["status"] for m in sent if m["type"] == "http.response.start")


def test_off_loopback_the_openigtlink_listener_stays_on_loopback_unless_told(tmp_path):
    settings = ServeSettings(
        host="0.0.0.0", igtl_port=0, token="s3cret-token", sessions_dir=tmp_path, compile=False, allowed_hosts=("Trainer.LAN",)
    )
    app = create_app(settings)  # run in this process: nothing listens beyond loopback

    async def served_off_loopback() -> None:
        async with app.router.lifespan_context(app):
            assert app.state.hub.igtl_address[0] == "127.0.0.1"
            bearer = {"Authorization": "Bearer s3cret-token"}
            assert await asgi_status(app, "/api/health", {**bearer, "Host": "trainer.lan:8000"}) == 200  # a name given with --allow-host
            assert await asgi_status(app, "/api/health", {**bearer, "Host": "192.168.4.1:8000"}) == 200  # an address
            assert await asgi_status(app, "/api/health", {**bearer, "Host": "evil.example"}) == 403
            assert await asgi_status(app, "/api/health", {"Host": "192.168.4.1:8000"}) == 401

    asyncio.run(served_off_loopback())
    remote = ServeSettings(
        host="0.0.0.0", token="s3cret-token", sessions_dir=tmp_path, igtl_host="0.0.0.0", igtl_allow=("192.168.4.0/24", "10.1.2.3")
    )
    remote.check()
    assert remote.igtl_config().host == "0.0.0.0"
    assert [str(n) for n in remote.igtl_config().allowed_peers] == ["127.0.0.0/8", "::1/128", "192.168.4.0/24", "10.1.2.3/32"]
