"""Helpers for the OpenIGTLink tests: a navigation server on 127.0.0.1 with an ephemeral port,
running its own event loop in a thread, and small blocking socket helpers (every read bounded by
a timeout). A module of its own (not conftest) so test files can import it by a unique name."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
import time

import numpy as np

from thrsim.io import igtl
from thrsim.io.server import IgtlServer


class RunningServer:
    def __init__(self, server: IgtlServer):
        self.server = server
        self.loop = asyncio.new_event_loop()
        started = threading.Event()

        def run() -> None:
            asyncio.set_event_loop(self.loop)
            self.host, self.port = self.loop.run_until_complete(server.start())
            started.set()
            self.loop.run_forever()

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        assert started.wait(5), "server did not start"

    def stop(self) -> None:
        if not self.thread.is_alive():
            return  # stopped already (a test stopped it; the fixture stops it again)
        asyncio.run_coroutine_threadsafe(self.server.close(), self.loop).result(5)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)

    def connect(self, timeout: float = 5.0) -> socket.socket:
        return socket.create_connection((self.host, self.port), timeout=timeout)


def recv_exactly(sock: socket.socket, size: int) -> bytes:
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        if not chunk:
            raise ConnectionError(f"closed after {len(data)} of {size} bytes")
        data += chunk
    return data


def read_message(sock: socket.socket) -> igtl.Message:
    header = igtl.parse_header(recv_exactly(sock, igtl.HEADER_SIZE))
    return igtl.decode_body(header, recv_exactly(sock, header.body_size))


def is_closed(sock: socket.socket, timeout: float = 5.0) -> bool:
    """True once the peer has closed (drains any pending replies first)."""
    sock.settimeout(timeout)
    with contextlib.suppress(ConnectionResetError, BrokenPipeError):
        while sock.recv(65536):
            continue
    return True


def reamer_pose_mm(inclination_deg: float = 40.0, anteversion_deg: float = 15.0) -> np.ndarray:
    """ReamerToReference for the default right synthetic pelvis; translation in mm, as on the wire."""
    ri, ra = np.radians(inclination_deg), np.radians(anteversion_deg)
    axis = np.array([np.cos(ra) * np.sin(ri), np.sin(ra), -np.cos(ra) * np.cos(ri)])
    x = np.cross([0.0, 1.0, 0.0], axis)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(axis, x), axis])
    pose[:3, 3] = [85.0, -35.0, -55.0]
    return pose


def transform_message(pose_mm: np.ndarray, device: str = "ReamerToReference", version: int = 1, metadata=None) -> bytes:
    pose_m = pose_mm.copy()
    pose_m[:3, 3] *= 1e-3
    return igtl.encode_message(igtl.Message("TRANSFORM", device, igtl.pack_transform(pose_m), version=version, metadata=metadata or {}))


def wait_until(predicate, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False
