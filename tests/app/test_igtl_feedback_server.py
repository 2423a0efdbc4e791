"""``thrsim serve --igtl-feedback`` with pyigtl as the peer (sockets on 127.0.0.1): a pyigtl client
streams a tracked reamer, a trainee's page drives a reaming session, and the client receives the
session's events as ``thrsimEvent`` STRING messages and the simulated reamer as the
``SimReamerToBone`` TRANSFORM, whose values match the page's state and the pose the client sent."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pyigtl
import pytest
from app_helpers import ServedTrainer, next_of_type, reamer_to_reference, wait_for
from websockets.sync.client import connect

from thrsim.app.navigation import NavigationTrainer
from thrsim.io.feedback import EVENT_DEVICE, SESSION_ENDED, SIM_REAMER_DEVICE
from thrsim.io.server import NAVIGATION_STATE
from thrsim.nav.bone_frame import angles_of, cup_angles_from_bone

pytestmark = pytest.mark.timeout(180)


class _Peer:
    """A pyigtl client sending ReamerToReference every 50 ms from a thread; every thrsimEvent it receives, kept."""

    def __init__(self, port: int, pose_m: np.ndarray):
        self.client = pyigtl.OpenIGTLinkClient("127.0.0.1", port)
        assert wait_for(self.client.is_connected, 10)
        self.pose_mm = pose_m.copy()
        self.pose_mm[:3, 3] *= 1e3
        self.events: list[dict] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.05):
            self.client.send_message(pyigtl.TransformMessage(self.pose_mm, device_name="ReamerToReference"), wait=False)

    def event(self, kind: str, timeout: float = 60.0) -> dict:
        """The first event of ``kind`` received (pyigtl keeps the newest message per device: poll it
        often; one message holds a step's events)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            message = self.client.wait_for_message(EVENT_DEVICE, timeout=0.005)
            if message is not None:
                self.events += json.loads(message.string)["events"]
            found = [e for e in self.events if e["kind"] == kind]
            if found:
                return found[0]
        raise AssertionError(f"no {kind} event; received {[e['kind'] for e in self.events]}")

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.client.stop()


def test_pyigtl_receives_the_events_and_the_simulated_reamer(tmp_path):
    served = ServedTrainer(tmp_path, "--igtl-feedback", timeout=120)
    pose = reamer_to_reference(NavigationTrainer(side="right").targets, 45.0, 20.0)
    peer = None
    try:
        peer = _Peer(served.igtl_port, pose)
        # the reply to the client's own pose: it round-trips
        reply = peer.client.wait_for_message(NAVIGATION_STATE, timeout=10)
        assert reply is not None
        assert np.allclose(np.array(json.loads(reply.string)["reamer_position_mm"]) * 1e-3, pose[:3, 3], atol=1e-6, rtol=0)
        with connect(f"ws://127.0.0.1:{served.port}/ws/reaming", open_timeout=10) as ws:
            hello = next_of_type(ws, "hello")
            session = hello["session"]
            patch_to_model = np.reshape(hello["scene"]["reaming"]["patch_to_model"], (4, 4))

            ws.send(json.dumps({"type": "probe", "action": "touch"}))  # the page's probe on the current landmark
            assert next_of_type(ws, "ack", timeout=60)["message"].startswith("probe on")
            acquired = peer.event("acquired")
            assert acquired["session"] == session and acquired["mode"] == "reaming" and acquired["landmark"]
            assert 0 < acquired["time_s"] < 60 and acquired["value"] < 5e-3  # within the acquisition tolerance

            size = next_of_type(ws, "state")["reaming"]["reamer"]["size_mm"]
            ws.send(json.dumps({"type": "reamer_size", "size_mm": size + 2}))
            assert next_of_type(ws, "ack", timeout=60)["message"] == f"reamer {size + 2} mm"
            swapped = peer.event("reamer_changed")
            assert (swapped["from_mm"], swapped["to_mm"], swapped["session"]) == (size, size + 2, session)

            ws.send(json.dumps({"type": "run", "action": "start"}))
            assert next_of_type(ws, "ack", timeout=60)["message"] == "reaming"
            assert peer.event("start")["session"] == session
            assert wait_for(lambda: next_of_type(ws, "state")["reaming"]["frame"] > 10, timeout=60)
            ws.send(json.dumps({"type": "run", "action": "pause"}))
            assert next_of_type(ws, "ack", timeout=60)["message"] == "paused"
            assert peer.event("pause")["frame"] > 10
            # paused, the simulated reamer holds still: every TRANSFORM and state from now on agree
            state = next_of_type(ws, "state")
            while state["reaming"]["running"]:
                state = next_of_type(ws, "state")
            assert state["tools"]["Reamer"]["source"] == "tracker"
            peer.client.wait_for_message(SIM_REAMER_DEVICE, timeout=0)  # one from before the pause, if any
            simulated = peer.client.wait_for_message(SIM_REAMER_DEVICE, timeout=5)
            assert simulated is not None
            matrix = np.array(simulated.matrix, dtype=float)
            matrix[:3, 3] *= 1e-3
            rotation = matrix[:3, :3]
            assert np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-6) and np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-6)
            centre = np.linalg.inv(patch_to_model) @ np.array([*state["reaming"]["reamer_centre"], 1.0])
            assert np.allclose(matrix[:3, 3], centre[:3], atol=1e-6, rtol=0)
            gamma, theta = np.radians([state["reaming"]["gamma_deg"], state["reaming"]["theta_deg"]])
            axis = [np.sin(gamma) * np.cos(theta), np.sin(gamma) * np.sin(theta), -np.cos(gamma)]  # D, into the bone
            assert np.allclose(rotation[:, 2], axis, atol=1e-6, rtol=0)
            # that axis is the tracked reamer's: the cup angles the client's pose was aimed at
            assert cup_angles_from_bone(*angles_of(rotation[:, 2])) == pytest.approx((45.0, 20.0), abs=1e-3)

            ws.send(json.dumps({"type": "end_session"}))
            saved = next_of_type(ws, "session_saved", timeout=60)
            ended = peer.event(SESSION_ENDED)
            assert (ended["session"], ended["file"], ended["mode"]) == (session, f"{saved['session']}.h5", "reaming")
    finally:
        if peer is not None:
            peer.stop()
        served.stop()
