"""What the trainer sends back (thrsim.io.feedback) and how the listener delivers it: one STRING per
step's events, the simulated reamer's pose in the bone frame, every peer fed without waiting on any,
a peer that stops reading misses messages instead of holding the others, and, with feedback on, a
viewer that reads what it is sent is not idle. Real sockets on 127.0.0.1; every wait bounded."""

from __future__ import annotations

import json
import math
import socket
import time

import numpy as np
import pytest
from igtl_helpers import is_closed, read_message, wait_until

from thrsim.config import IgtlConfig
from thrsim.io import feedback, igtl
from thrsim.nav.bone_frame import angles_of

pytestmark = pytest.mark.timeout(60)


def test_the_reamer_pose_has_its_axis_along_d_and_the_gamma_zero_rotation():
    assert np.array_equal(feedback.reamer_to_bone(0.0, 0.0, np.zeros(3)), np.diag([1.0, -1.0, -1.0, 1.0]))
    for gamma, theta in [(12.0, 30.0), (45.0, 200.0), (3.0, 359.0)]:
        pose = feedback.reamer_to_bone(gamma, theta, np.array([0.001, -0.002, 0.003]))
        rotation = pose[:3, :3]
        assert np.allclose(rotation.T @ rotation, np.eye(3)) and np.linalg.det(rotation) == pytest.approx(1.0)
        assert angles_of(rotation[:, 2]) == pytest.approx((gamma, theta))
        assert np.array_equal(pose[:3, 3], [0.001, -0.002, 0.003]) and np.array_equal(pose[3], [0, 0, 0, 1])


def test_a_steps_events_are_sent_once_each_in_one_string():
    acquired = {"time_s": 1.5, "kind": "acquired", "landmark": "asis_right", "detail": "", "value": 0.001}
    start = {"time_s": 1.5, "kind": "start", "detail": "", "frame": 0}
    early = {"mode": "reaming", "events": [acquired], "reaming": {"events": [start]}}
    final = {"mode": "reaming", "events": [acquired], "reaming": {"events": []}}  # the navigation events ride along again
    events = feedback.step_events("S1", [early, final])
    assert [e["kind"] for e in events] == ["acquired", "start"] and {e["session"] for e in events} == {"S1"}
    assert feedback.step_events("S1", [{"mode": "navigation", "events": []}]) == []
    type_name, device, content = feedback.events_message(events)
    assert (type_name, device) == ("STRING", feedback.EVENT_DEVICE)
    assert json.loads(igtl.unpack_string(content))["events"][0] == {**acquired, "session": "S1", "mode": "reaming"}


def test_the_simulated_reamer_is_given_in_the_patch_frame_once_placed():
    patch_to_model = np.eye(4)
    patch_to_model[:3, :3] = np.diag([-1.0, 1.0, 1.0])  # a left hip's mirror
    patch_to_model[:3, 3] = [0.05, 0.0, 0.1]
    scene = {"reaming": {"patch_to_model": patch_to_model.ravel().tolist()}}
    state = {"reaming": {"reamer_centre": [0.04, 0.002, 0.09], "gamma_deg": 10.0, "theta_deg": 90.0}}
    type_name, device, content = feedback.simulated_reamer(state, lambda: scene)
    assert (type_name, device) == ("TRANSFORM", feedback.SIM_REAMER_DEVICE)
    pose = igtl.unpack_transform(content)
    assert np.allclose(pose[:3, 3], [0.01, 0.002, -0.01], atol=1e-9)  # mm on the wire, float32
    assert np.allclose(pose[:3, 2], [0.0, math.sin(math.radians(10.0)), -math.cos(math.radians(10.0))], atol=1e-7)
    unplaced = {"reaming": {"reamer_centre": None, "gamma_deg": 10.0, "theta_deg": 90.0}}
    assert feedback.simulated_reamer(unplaced, lambda: pytest.fail("the scene is not needed")) is None
    assert feedback.simulated_reamer({"mode": "navigation"}, lambda: scene) is None


def _feed(server, messages) -> None:
    server.loop.call_soon_threadsafe(server.server.broadcast, messages)


def test_every_peer_gets_the_feedback_and_one_that_stops_reading_misses_it_alone(make_server):
    # (an I/O timeout longer than the test's wait for the server to stop)
    server = make_server(IgtlConfig(port=0, feedback=True, max_body_bytes=16 * 1024, io_timeout_s=30))
    event = feedback.events_message([feedback.session_ended("S1", "reaming", 12.5, "S1.h5")])
    chunk = ("STRING", feedback.EVENT_DEVICE, igtl.pack_string("x" * 8000))
    stalled = socket.socket()
    stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # small kernel buffers: a few messages fill them
    stalled.settimeout(5)
    stalled.connect((server.host, server.port))
    with server.connect() as reader, stalled:
        assert wait_until(lambda: server.server.clients == 2)
        port = stalled.getsockname()[1]
        for connection in list(server.server._connections):
            if connection.writer.get_extra_info("peername")[1] == port:
                connection.writer.get_extra_info("socket").setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
        _feed(server, [event])
        for sock in (reader, stalled):
            message = read_message(sock)
            assert (message.type_name, message.device_name) == ("STRING", feedback.EVENT_DEVICE)
            assert json.loads(igtl.unpack_string(message.content))["events"][0]["kind"] == feedback.SESSION_ENDED
        for _ in range(100):  # 800 kB: far more than the stalled peer's buffers hold
            _feed(server, [chunk])
            assert igtl.unpack_string(read_message(reader).content) == "x" * 8000  # every one, in turn
        stats = server.server.stats  # the server's loop thread may still be writing the last message to the stalled peer
        assert wait_until(lambda: stats["feedback_sent"] + stats["feedback_dropped"] == 2 + 2 * 100)
        assert stats["feedback_dropped"] > 50  # the stalled peer's, which held nobody up
        server.stop()  # with the stalled peer still connected: its unsent feedback does not hold the close open
        assert is_closed(stalled)


def test_with_feedback_a_viewer_reading_it_is_not_idle_until_the_feedback_stops(make_server):
    server = make_server(IgtlConfig(port=0, feedback=True, idle_timeout_s=0.4))
    with server.connect() as viewer:  # it never sends a message
        assert wait_until(lambda: server.server.clients == 1)
        deadline = time.monotonic() + 1.6  # four idle timeouts
        while time.monotonic() < deadline:
            _feed(server, [("STRING", feedback.EVENT_DEVICE, igtl.pack_string('{"events": []}'))])
            assert read_message(viewer).device_name == feedback.EVENT_DEVICE
            time.sleep(0.05)
        assert server.server.clients == 1 and server.server.stats["idle_timeouts"] == 0
        # no more feedback: an idle timeout later the viewer is idle like any other connection
        viewer.settimeout(5)
        code, name, _ = igtl.unpack_status(read_message(viewer).content)
        assert (code, name) == (igtl.STATUS_TIMEOUT, "IdleTimeout") and is_closed(viewer)
    assert server.server.stats["idle_timeouts"] == 1
