"""Helpers for the trainer tests: a real ``python -m thrsim serve`` on free 127.0.0.1 ports, a
tiny OpenIGTLink client and a WebSocket client, every wait bounded. A module of its own (not
conftest) so test files import it by a unique name."""

from __future__ import annotations

import io
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from thrsim.io import igtl

REPO = Path(__file__).resolve().parents[2]


def checkout_env(**extra: str) -> dict[str, str]:
    """This environment with this checkout first on PYTHONPATH: a child ``python -m thrsim`` runs
    this code whatever its working directory, even where another checkout is installed."""
    rest = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and Path(p).resolve() != REPO]
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), *rest]), **extra}


_ANNOUNCE = re.compile(r"http://127\.0\.0\.1:(\d+)/.*OpenIGTLink on 127\.0\.0\.1:(\d+)")


class ServedTrainer:
    """``thrsim serve`` in a child process; ``stop()`` ends it with SIGTERM (as a user's Ctrl-C).

    The reaming network runs uncompiled unless ``compile``: compiling costs 10–30 s at start,
    so only the tests about it pay for it (the two kinds remove the same bone; see
    tests/learn/test_learn_simulator.py).
    """

    def __init__(self, sessions: Path, *extra: str, timeout: float = 60.0, compile: bool = False, env: dict[str, str] | None = None):
        self.sessions = sessions
        flags = () if compile else ("--no-compile",)
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "thrsim",
                "serve",
                "--port",
                "0",
                "--igtl-port",
                "0",
                "--sessions",
                str(sessions),
                "--seed",
                "7",
                *flags,
                *extra,
            ],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=checkout_env(PYTHONUNBUFFERED="1", **(env or {})),
        )
        self.lines: list[str] = []
        found = threading.Event()

        def read() -> None:
            for line in self.process.stdout:
                self.lines.append(line)
                if _ANNOUNCE.search(line):
                    found.set()

        self.error_lines: list[str] = []  # read as it comes: a full pipe would block the server's logging

        def read_errors() -> None:
            for line in self.process.stderr:
                self.error_lines.append(line)

        threading.Thread(target=read, daemon=True).start()
        self._error_reader = threading.Thread(target=read_errors, daemon=True)
        self._error_reader.start()
        if not found.wait(timeout):
            self.stop()
            raise RuntimeError(f"thrsim serve did not start: {self.stderr()[-2000:]}")
        match = next(_ANNOUNCE.search(line) for line in self.lines if _ANNOUNCE.search(line))
        self.port, self.igtl_port = int(match.group(1)), int(match.group(2))
        self.url = f"http://127.0.0.1:{self.port}"

    def stop(self, timeout: float = 20.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
        return self.process.returncode

    def stderr(self) -> str:
        """What the server wrote to stderr, once it has exited ("" while it runs)."""
        if self.process.poll() is None:
            return ""
        self._error_reader.join(10)
        return "".join(self.error_lines)


def reamer_to_reference(trainer_side_targets: dict, inclination_deg: float, anteversion_deg: float) -> np.ndarray:
    """A ReamerToReference pose (metres) at radiographic angles in the planned APP of the targets."""
    from thrsim.nav.anatomy import app_frame, local_axis_from_angles

    frame = app_frame(trainer_side_targets)
    axis = frame.to_world(local_axis_from_angles(inclination_deg, anteversion_deg))
    x = np.cross(frame.anterior, axis)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(axis, x), axis])
    pose[:3, 3] = np.mean(list(trainer_side_targets.values()), axis=0)
    return pose


def send_force(port: int, newton: float, device: str = "ForceSensor", timeout: float = 5.0) -> igtl.Message:
    """Send one SENSOR message of a push force (N) and return the reply."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as sock:
        sock.sendall(igtl.encode_message(igtl.Message("SENSOR", device, igtl.pack_sensor([newton]))))
        return read_message(sock)


def send_transform(
    port: int, device: str, pose_m: np.ndarray, count: int = 1, interval_s: float = 0.0, timeout: float = 5.0
) -> igtl.Message:
    """Send TRANSFORM message(s) of a pose in metres (the codec writes mm) and return the last reply."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as sock:
        reply = None
        for _ in range(count):
            sock.sendall(igtl.encode_message(igtl.Message("TRANSFORM", device, igtl.pack_transform(pose_m))))
            reply = read_message(sock)
            if interval_s:
                time.sleep(interval_s)
        return reply


def read_message(sock: socket.socket) -> igtl.Message:
    def exactly(size: int) -> bytes:
        data = b""
        while len(data) < size:
            chunk = sock.recv(size - len(data))
            if not chunk:
                raise ConnectionError("closed")
            data += chunk
        return data

    header = igtl.parse_header(exactly(igtl.HEADER_SIZE))
    return igtl.decode_body(header, exactly(header.body_size))


def next_of_type(ws, kind: str, limit: int = 2000, timeout: float = 10.0) -> dict:
    """The next JSON message of ``kind`` on a websockets sync connection (bounded; binary frames skipped)."""
    deadline = time.monotonic() + timeout
    for _ in range(limit):
        raw = ws.recv(timeout=max(0.01, deadline - time.monotonic()))
        if isinstance(raw, bytes):
            continue
        message = json.loads(raw)
        if message["type"] == kind:
            return message
    raise AssertionError(f"no {kind} message in {limit} messages")


def wait_for(predicate, timeout: float = 10.0, step: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return False


def picture(page) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(page.locator("#view").screenshot())).convert("RGB"), dtype=np.int16)


def changed_fraction(before: np.ndarray, after: np.ndarray) -> float:
    return float(np.mean(np.abs(before - after).sum(axis=2) > 30))


def keys(page, key: str) -> None:
    """A key press as a user makes it, with no control focused (Space must not click a button)."""
    page.evaluate("document.activeElement && document.activeElement.blur()")
    page.keyboard.press(key)


class SocketSession:
    """The shipped socket model's reaming session run in-process on a clock the test moves (``tick``:
    one simulator frame), the native 46 mm socket meshed at ``element_mm``."""

    def __init__(self, folder: Path, element_mm: float, step_s: float = 1 / 60):
        from thrsim.app.live import LiveSession
        from thrsim.app.modes import MODES
        from thrsim.learn.model_dir import SHIPPED_SOCKET_MODEL

        self.now, self.step_s, self.folder = 0.0, step_s, folder
        settings = {"side": "right", "seed": 1, "model": str(SHIPPED_SOCKET_MODEL), "socket_element_size_mm": element_mm}
        self.live = LiveSession(MODES["reaming"], settings, lambda: self.now, folder)

    def send(self, **message) -> str:
        return self.live.control(json.dumps(message))[1]

    def tick(self) -> dict:
        self.now += self.step_s
        return self.live.tick()["reaming"]


def own_bone_left(mesh, node_set: str):
    """The test's own reading of the bone left before a face (``node_set``): the distance (mm) from the
    teeth sphere to the nearest node of the remaining elements with a node on it, 0 once one is gone."""
    elements = np.flatnonzero(np.isin(mesh.tets, mesh.node_sets[node_set]).any(axis=1))
    nodes = mesh.nodes[np.unique(mesh.tets[elements])]

    def left(trainer, teeth_m: float) -> float:
        if trainer.simulator.removed[elements].any():
            return 0.0
        return max(0.0, (np.linalg.norm(nodes - trainer._reamer_position, axis=1).min() - teeth_m) * 1e3)

    return left
