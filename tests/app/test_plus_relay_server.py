"""The PLUS set-up's message flow against a real ``thrsim serve``: a stand-in PlusServer on
127.0.0.1 streams what the shipped device set streams (its transform names, poses in mm, as
PLUS's transform repository composes them), the relay script of the tracker page (docs/tracker.md)
runs as it is written, ports aside, and the trainer's page sees every tool from the tracker, the
reamer aimed where the stand-in aimed it."""

from __future__ import annotations

import contextlib
import re
import socket
import subprocess
import sys
import threading
import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest
from app_helpers import REPO, ServedTrainer, checkout_env, next_of_type, reamer_to_reference
from websockets.sync.client import connect

from thrsim.app.navigation import NavigationTrainer
from thrsim.config import OPENIGTLINK_PORT
from thrsim.io import igtl
from thrsim.io.plus import device_set

pytestmark = pytest.mark.timeout(180)


def _relay_script() -> str:
    """The tracker page's relay from PlusServer to thrsim (the Python block that reads PlusServer's messages)."""
    blocks = re.findall(r"```python\n(.*?)```", (REPO / "docs" / "tracker.md").read_text(), re.DOTALL)
    [relay] = [block for block in blocks if "get_latest_messages" in block]
    return relay


class _StandInPlusServer:
    """Listens on a free port; to its one client, the device set's transforms every 30 ms until stopped."""

    def __init__(self, poses_m: dict[str, np.ndarray]):
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.poses_m = poses_m
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        self.listener.settimeout(60)
        connection, _ = self.listener.accept()
        with connection, contextlib.suppress(ConnectionError):  # the client leaving ends the stream, as in PlusServer
            while not self._stop.wait(0.03):
                for name, pose in self.poses_m.items():
                    connection.sendall(igtl.encode_message(igtl.Message("TRANSFORM", name, igtl.pack_transform(pose))))
                    self.sent += 1

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.listener.close()


def test_the_documented_relay_brings_plus_transforms_to_a_real_serve(tmp_path):
    streamed = [t.get("Name") for t in ElementTree.fromstring(device_set("ndi")).iterfind(".//TransformNames/Transform")]
    trainer = NavigationTrainer(side="right")
    reference_to_tracker = np.linalg.inv(trainer.camera_pose)  # the camera where the page puts it: every tool in view
    probe_to_reference = np.eye(4)
    probe_to_reference[:3, 3] = [0.05, 0.15, 0.02]
    reamer_to_reference_pose = reamer_to_reference(trainer.targets, 45.0, 20.0)
    composed = {  # what PLUS's transform repository makes of the tools it tracks
        "ReferenceToTracker": reference_to_tracker,
        "ProbeToReference": probe_to_reference,
        "ReamerToReference": reamer_to_reference_pose,
        "ProbeToTracker": reference_to_tracker @ probe_to_reference,
        "ReamerToTracker": reference_to_tracker @ reamer_to_reference_pose,
    }
    assert sorted(composed) == sorted(streamed)
    served = ServedTrainer(tmp_path, timeout=120)
    plus = _StandInPlusServer(composed)
    script = _relay_script()
    assert script.count(str(OPENIGTLINK_PORT)) == 1 and script.count("18945") == 1
    script = script.replace(str(OPENIGTLINK_PORT), str(plus.port)).replace("18945", str(served.igtl_port))
    relay = subprocess.Popen([sys.executable, "-c", script], stderr=subprocess.PIPE, text=True, env=checkout_env())
    try:  # (the relay's stderr is read only once it has stopped: it writes nothing while it works)
        with connect(f"ws://127.0.0.1:{served.port}/ws/navigation", open_timeout=10) as ws:
            next_of_type(ws, "hello")
            for _ in range(3000):
                state = next_of_type(ws, "state", timeout=30)
                tools, camera = state["tools"], state["camera"]
                if camera["source"] == "tracker" and all(tools[name]["source"] == "tracker" for name in ("Probe", "Reamer")):
                    break
            assert camera["source"] == "tracker", camera
            assert {name: tools[name]["source"] for name in ("Probe", "Reamer")} == {"Probe": "tracker", "Reamer": "tracker"}
            assert state["angles"]["radiographic"] == pytest.approx([45.0, 20.0], abs=0.01)
        assert relay.poll() is None, relay.stderr.read()  # the relay runs until it is stopped
        assert plus.sent >= len(streamed)
    finally:
        plus.stop()
        relay.kill()
        relay.wait(10)
        served.stop()
