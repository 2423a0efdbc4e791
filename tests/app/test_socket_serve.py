"""``thrsim serve --model SOCKET_MODEL`` end to end, on 127.0.0.1: a real server reaming the whole
socket with a tiny whole-socket model; a pyigtl client receives each frame's ``ReamerReaction`` and
``ReamerTorque`` SENSORs with the values the saved session records; the haptic stream sends at least
1000 messages a second whose force is the one the next frame records; a fresh process replays the
session exactly; and the reaming page in a
headless Chromium draws the socket and shows the force and what lies outside what the model learned."""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import socket
import threading
import time

import numpy as np
import pyigtl
import pytest
from app_helpers import ServedTrainer, keys, next_of_type, wait_for
from checkout_cli import run_thrsim
from pyigtl_sensor import register
from websockets.sync.client import connect

from thrsim.app.drawing_bench import CHROMIUM
from thrsim.config import SocketConfig
from thrsim.io import igtl
from thrsim.io.feedback import REACTION_DEVICE, TORQUE_DEVICE
from thrsim.io.igtl import UNIT_NEWTON, UNIT_NEWTON_METRE
from thrsim.session.file import read_session
from thrsim.session.reaming import read_reaming

pytestmark = pytest.mark.timeout(900)


@pytest.fixture(scope="module")
def served(tiny_socket_model, tmp_path_factory):
    served = ServedTrainer(
        tmp_path_factory.mktemp("sessions"),
        *("--model", str(tiny_socket_model), "--igtl-feedback", "--haptic-port", "0", "--socket-element-size", "5"),
        timeout=600,
    )
    found = [re.search(r"haptic stream on 127\.0\.0\.1:(\d+)", line) for line in served.lines]
    served.haptic_port = int(next(match for match in found if match).group(1))
    yield served
    served.stop()


class _HapticClient:
    """Reads the haptic stream on a thread: (arrival time, device, value, unit) of every message. It
    reads in bulk and checks the CRC of every 100th message only, so that on a loaded machine the
    client, not the stream, is never what is measured."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.received: list[tuple[float, str, float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        buffer = bytearray()
        with contextlib.suppress(OSError):  # the test closed the socket
            while not self._stop.is_set():
                buffer += self.sock.recv(1 << 16)
                arrived = time.monotonic()
                while len(buffer) >= igtl.HEADER_SIZE:
                    header = igtl.parse_header(bytes(buffer[: igtl.HEADER_SIZE]))
                    end = igtl.HEADER_SIZE + header.body_size
                    if len(buffer) < end:
                        break
                    body = bytes(buffer[igtl.HEADER_SIZE : end])
                    del buffer[:end]
                    if len(self.received) % 100 == 0:
                        igtl.decode_body(header, body)  # raises on a bad CRC
                    assert header.type_name == "SENSOR"
                    values, unit = igtl.unpack_sensor(body)
                    self.received.append((arrived, header.device_name, float(values[0]), unit))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.sock.close()


def test_the_force_goes_to_the_tracker_client_and_the_haptic_stream_as_recorded(served, tiny_socket_model):
    register()  # pyigtl reads SENSOR messages
    client = pyigtl.OpenIGTLinkClient("127.0.0.1", served.igtl_port)
    haptic = _HapticClient(served.haptic_port)
    reactions: list[float] = []
    torques: list[float] = []
    try:
        assert wait_for(client.is_connected, 10)
        with connect(f"ws://127.0.0.1:{served.port}/ws/reaming", open_timeout=30) as ws:
            hello = next_of_type(ws, "hello", timeout=60)
            assert hello["scene"]["reaming"]["available"], hello["scene"]["reaming"]["unavailable"]
            size = next_of_type(ws, "state", timeout=30)["reaming"]["reamer"]["size_mm"]
            ws.send(json.dumps({"type": "force", "newton": 400}))
            ws.send(json.dumps({"type": "run", "action": "start"}))
            assert wait_for(lambda: next_of_type(ws, "state", timeout=30)["reaming"]["frame"] > 3, timeout=120)
            for reamer in (size, size + 2):
                if reamer != size:  # the next reamer: its law, its force
                    ws.send(json.dumps({"type": "reamer_size", "size_mm": reamer}))
                    ws.send(json.dumps({"type": "run", "action": "start"}))
                deadline = time.monotonic() + 3.0
                while time.monotonic() < deadline:  # pyigtl keeps the newest message of a device: poll it often
                    for device, values in ((REACTION_DEVICE, reactions), (TORQUE_DEVICE, torques)):
                        message = client.wait_for_message(device, timeout=0.002)
                        if message is not None:
                            assert message.unit == (UNIT_NEWTON if device == REACTION_DEVICE else UNIT_NEWTON_METRE)
                            values += message.values
                    ws.recv(timeout=1)  # keep the page's stream drained
            ws.send(json.dumps({"type": "run", "action": "pause"}))
            ws.send(json.dumps({"type": "end_session"}))
            saved = next_of_type(ws, "session_saved", timeout=120)
    finally:
        haptic.stop()
        client.stop()
    record = read_reaming(read_session(saved["file"]).groups["reaming"])
    assert record.reaction_n is not None and len(record.reaction_n) > 10
    recorded_reactions, recorded_torques = set(record.reaction_n.tolist()), set(record.motor_torque_n_m.tolist())
    # every frame's force went out as the session records it, both reamers' (their laws, and so their torques, differ);
    # the bone takes no more than the 400 N pushed (the tiny model's stiff law stalls the reamer: it takes all of it)
    assert len(reactions) >= 5 and set(reactions) <= recorded_reactions and max(reactions) <= 400.0
    assert len(torques) >= 5 and set(torques) <= recorded_torques and len(set(torques)) >= 2
    # the haptic stream: at least 1000 force messages in a second (counted from half a second in)
    forces = [(at, value) for at, device, value, unit in haptic.received if device == REACTION_DEVICE and unit == UNIT_NEWTON]
    assert forces, haptic.received[:5]
    start = forces[0][0] + 0.5
    assert sum(start <= at < start + 1.0 for at, _ in forces) >= 1000
    # between frames, the force the next frame records (nothing while the reamer was paused for the swap)
    felt = np.array([value for _, value in forces if value != 0.0])
    assert len(felt) > 100
    nearest = np.min(np.abs(felt[:, None] - np.array(sorted(recorded_reactions))[None, :]), axis=1)
    assert np.mean(nearest <= 1e-9 * np.abs(felt)) > 0.95  # the last law of each reamer precedes no frame
    # a fresh process meshes the case's socket again and relives the served session exactly, forces and all
    replayed = run_thrsim("replay", saved["file"], "--model", str(tiny_socket_model), "--json", timeout=600)
    assert replayed.returncode == 0 and json.loads(replayed.stdout)["reproduced"], replayed.stdout + replayed.stderr


@pytest.mark.skipif(shutil.which(CHROMIUM) is None, reason="Debian chromium is not installed (./install.sh installs it)")
def test_the_page_draws_the_socket_and_shows_the_force_live(served, browser):
    page = browser.new_page(viewport={"width": 1100, "height": 720})
    problems: list[str] = []
    page.on("pageerror", lambda error: problems.append(str(error)))
    page.goto(served.url + "/reaming", timeout=60_000)
    page.wait_for_function("window.trainer && trainer.stats.states > 5 && trainer.stats.visibleFaces > 0", timeout=180_000)
    elements = page.evaluate("trainer.stats.hello.scene.reaming.elements")
    assert page.evaluate("trainer.bone().mesh.tets") == elements and elements > 1000  # the socket, not the patch
    assert page.evaluate("trainer.bone().mesh.materialNames") == ["cortical", "cancellous"]
    assert page.locator(".force-row").first.is_hidden()  # no force before the first frame
    native = f"a {SocketConfig().socket_diameter_mm:g} mm socket, normal bone"  # the default case's, in the plan
    page.wait_for_function(f"document.getElementById('plan-summary').textContent.endsWith('{native}')", timeout=30_000)
    keys(page, "Space")
    page.wait_for_function("trainer.stats.last.reaming.reaction_n !== null", timeout=120_000)
    shown = "document.getElementById('reaction').textContent === trainer.stats.last.reaming.reaction_n.toFixed(0) + ' N'"
    page.wait_for_function(shown, timeout=30_000)
    page.wait_for_function(
        "document.getElementById('torque').textContent === trainer.stats.last.reaming.motor_torque_n_m.toFixed(2) + ' N·m'", timeout=30_000
    )
    assert page.locator(".force-row").first.is_visible()
    width = page.evaluate("parseFloat(document.getElementById('reaction-bar').style.width)")
    reaction, most = page.evaluate("[trainer.stats.last.reaming.reaction_n, trainer.stats.hello.defaults.max_force_n]")
    assert width == pytest.approx(min(100.0, 100 * reaction / most), abs=0.1) and width > 0
    # the synthetic cases were reamed with one reamer: the trainee's first lies outside what the model learned, and the page
    # says so (a socket model reads the feed, not the push: no push is out of its range)
    page.wait_for_function("document.getElementById('out-of-range').textContent.includes('reamer')", timeout=30_000)
    events = page.evaluate("trainer.stats.events")
    assert "reamer_out_of_range" in events and "push_out_of_range" not in events
    keys(page, "Space")
    assert not problems
    page.close()
