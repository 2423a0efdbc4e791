"""Inputs that arrive during a slow tick, on a real trainer served in this process (uvicorn on
127.0.0.1, the shipped patch model, an OpenIGTLink tracker and a WebSocket page), its clock the
test's: one simulator step is held until the test has sent, three frames apart on that clock,
tracked reamer poses and the page's pushes. Meanwhile the page's WebSocket and the tracker are
still answered; afterwards the inputs apply over the next ticks in the order they came (twice as
fast as they came), each frame reaming with the pose and the push of its own time, none dropped and
none merged, and the session file keeps them in that order and replays exactly."""

from __future__ import annotations

import json
import socket
import threading
import time

import pytest
import uvicorn
from app_helpers import next_of_type, reamer_to_reference, send_transform, wait_for
from websockets.sync.client import connect

from thrsim.app.navigation import NavigationTrainer
from thrsim.app.replay import replay_session
from thrsim.app.server import ServeSettings, create_app
from thrsim.learn.simulator import ReamingSimulator
from thrsim.session import read_session
from thrsim.session.reaming import read_reaming

pytestmark = pytest.mark.timeout(300)

STEP = 1 / 60
#: what the tracker and the page send while the step is held: the reamer's radiographic angles and the push
SENT = [((36.0, 15.0), 180.0), ((40.0, 19.0), 210.0), ((44.0, 15.0), 240.0), ((48.0, 11.0), 270.0)]


class _Clock:
    """The trainer's clock, moved by the test only (from the monotonic clock's now, where the hub's began)."""

    def __init__(self) -> None:
        self.now = time.monotonic()

    def __call__(self) -> float:
        return self.now


class _Hold:
    """Holds the simulator's next step (once armed) until released: a slow tick, as long as the test needs."""

    def __init__(self) -> None:
        self.armed, self.entered, self.released = threading.Event(), threading.Event(), threading.Event()


@pytest.fixture
def served(tmp_path, monkeypatch):
    hold = _Hold()
    real_step = ReamingSimulator.step

    def step(self, *args, **kwargs):
        if hold.armed.is_set():
            hold.armed.clear()
            hold.entered.set()
            assert hold.released.wait(120)
        return real_step(self, *args, **kwargs)

    monkeypatch.setattr(ReamingSimulator, "step", step)
    app = create_app(ServeSettings(port=0, igtl_port=0, sessions_dir=tmp_path, compile=False, seed=7))
    clock = _Clock()
    app.state.hub.clock = clock  # before the lifespan: the OpenIGTLink listener and every session read it
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [listener]}, daemon=True)
    thread.start()
    assert wait_for(lambda: getattr(app.state, "ready", False), timeout=120)
    yield app, clock, hold, listener.getsockname()[1]
    hold.released.set()
    server.should_exit = True
    thread.join(30)
    listener.close()


def _tick_passes(hub) -> None:
    """Wait until a whole tick has run after now (the ticker runs on real time; the clock is the test's)."""
    start = hub.ticks
    assert wait_for(lambda: hub.ticks >= start + 2, timeout=30, step=0.005)


def test_inputs_that_arrive_during_a_slow_tick_apply_in_order_one_per_frame(served):
    app, clock, hold, port = served
    hub = app.state.hub
    targets = NavigationTrainer(side="right").targets
    igtl_port = hub.igtl_address[1]
    with connect(f"ws://127.0.0.1:{port}/ws/reaming", open_timeout=30) as page:
        next_of_type(page, "hello")
        session = hub.seats[0].session
        send_transform(igtl_port, "ReamerToReference", reamer_to_reference(targets, 40.0, 15.0))
        page.send(json.dumps({"type": "force", "newton": 150}))
        page.send(json.dumps({"type": "run", "action": "start"}))
        assert next_of_type(page, "ack")["message"] == "push 150 N" and next_of_type(page, "ack")["message"] == "reaming"
        clock.now += STEP
        assert wait_for(lambda: session.trainer.frames_run == 1, timeout=30)
        hold.armed.set()
        clock.now += STEP
        assert hold.entered.wait(30)  # the tick stepping frame 2 is held: the session's lock with it
        for k, ((inclination, anteversion), push) in enumerate(SENT):
            clock.now += 3 * STEP
            reply = send_transform(igtl_port, "ReamerToReference", reamer_to_reference(targets, inclination, anteversion))
            assert reply.type_name == "STRING"  # the tracker is answered during the slow tick
            page.send(json.dumps({"type": "force", "newton": push}))
            assert wait_for(lambda k=k: len(session._arrived) == 2 * (k + 1), timeout=10)  # both queued, none applied
        assert session.trainer.frames_run == 1
        hold.released.set()
        _tick_passes(hub)
        for _ in range(3 * len(SENT) + 2):
            clock.now += STEP
            _tick_passes(hub)
        acks = [next_of_type(page, "ack")["message"] for _ in SENT]
        assert acks == [f"push {push:g} N" for _, push in SENT]  # each page control answered, in order
        page.send(json.dumps({"type": "run", "action": "pause"}))
        clock.now += STEP
        next_of_type(page, "ack")
        page.send(json.dumps({"type": "end_session"}))
        clock.now += STEP
        saved = next_of_type(page, "session_saved", timeout=30)

    session_file = read_session(saved["file"])
    record = read_reaming(session_file.groups["reaming"])
    frames = [(round(float(a), 1), round(float(b), 1), float(f)) for (a, b, _), f in zip(record.angles, record.force_n, strict=True)]
    # frames 1 and 2 (the held one) and those of the tick after it (which fell behind) ream with what came before
    assert frames[:3] == [(40.0, 15.0, 150.0)] * 3
    runs = [frame for row, frame in enumerate(frames) if row == 0 or frame != frames[row - 1]]
    # every pose and push sent during the held step reamed frames of its own, in the order sent: none dropped, none merged
    assert runs == [(40.0, 15.0, 150.0)] + [(inclination, anteversion, push) for (inclination, anteversion), push in SENT]
    # the file keeps them in arrival order, at their arrival times, and the session replays exactly
    inputs = [(kind, time_s, payload) for kind, time_s, payload in session_file.inputs.replay() if kind != "tick"]
    during = [(kind, payload) for kind, time_s, payload in inputs if 2 * STEP < time_s]
    assert [kind for kind, _ in during[: 2 * len(SENT)]] == ["pose", "control"] * len(SENT)
    assert [payload["newton"] for kind, payload in during[: 2 * len(SENT)] if kind == "control"] == [push for _, push in SENT]
    assert replay_session(saved["file"]).reproduced
