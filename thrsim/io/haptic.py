"""The force a haptic device renders, streamed far faster than the simulator's frames (``thrsim serve --haptic-port``).

A HIPS-style haptic loop runs at 1 kHz and needs an answer within a millisecond; the simulator
steps a frame each 1/60 s. Between frames :class:`ContactForce` evaluates the reaction law the
whole-socket model predicted for the next frame, R = A + B·v (torque likewise), at the feed the
newest push F gives against it and the hold's damping c, v = max(0, F − A) / (B + c), the very
rule that frame's feed follows (:mod:`thrsim.learn.reaction_feed`): so a frame records what the
stream sent before it, and a change of push is felt within one period instead of a frame. Nothing
reams (paused, hidden, a patch model): zero. :class:`HapticStream` sends the pair of SENSORs of
:mod:`thrsim.io.feedback` to every client on its own thread, once a period, never in a burst.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import socket
import sys
import threading
import time
from dataclasses import dataclass

from thrsim.io import igtl
from thrsim.io.feedback import force_messages

log = logging.getLogger(__name__)

#: a client holding this much unsent (it does not read) misses messages until it has read them
_MAX_UNSENT_BYTES = 64 * 1024


@dataclass(frozen=True)
class _Contact:
    law: tuple[float, float, float, float]  # A (N), B (N·s/m), A_torque (N·m), B_torque (N·m·s/m)
    damping_n_s_m: float
    force_n: float  # the push when the law was read
    read_at: float  # when (time.monotonic)


class ContactForce:
    """The fast contact model: the latest law and push, read and replaced whole (safe across threads)."""

    def __init__(self) -> None:
        self._contact: _Contact | None = None
        self._sensor: tuple[float, float] | None = None  # the newest force sensor reading (N) and when

    def follow(self, contact: dict | None) -> None:
        """A trainer step's ``contact`` (its law, the hold's damping and the push), or None when nothing reams."""
        if contact is None:
            self._contact = None
            return
        law = tuple(float(v) for v in contact["law"])
        self._contact = _Contact(
            (law[0], law[1], law[2], law[3]), float(contact["damping_n_s_m"]), float(contact["force_n"]), time.monotonic()
        )

    def push(self, newton: float) -> None:
        """A force sensor's reading, felt before the next frame reads it."""
        self._sensor = (float(newton), time.monotonic())

    def now(self) -> tuple[float, float]:
        """(reaction N, motor torque N·m) at the newest push."""
        contact, sensor = self._contact, self._sensor
        if contact is None:
            return 0.0, 0.0
        force = sensor[0] if sensor is not None and sensor[1] > contact.read_at else contact.force_n
        a, b, a_torque, b_torque = contact.law
        feed = max(0.0, force - a) / (b + contact.damping_n_s_m)
        return a + b * feed, a_torque + b_torque * feed


class HapticStream:
    """An OpenIGTLink server that only sends: ``ReamerReaction`` and ``ReamerTorque`` SENSORs every
    ``1/rate_hz`` s to each client from ``allowed`` networks (others are closed at once)."""

    def __init__(self, host: str, port: int, rate_hz: float, allowed: tuple[str, ...], force: ContactForce):
        self.host, self.port, self.rate_hz, self.force = host, port, rate_hz, force
        self.allowed = tuple(ipaddress.ip_network(network) for network in allowed)
        self.stats = {"periods": 0, "sent": 0, "dropped": 0, "clients": 0, "refused_peers": 0}
        self._clients: dict[socket.socket, bytearray] = {}
        self._stop = threading.Event()
        self._listener: socket.socket | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> tuple[str, int]:
        """Listen and start sending; the bound (host, port) (the OS picks a port for 0). The interpreter
        then hands its lock between threads every 0.5 ms instead of 5 ms, so that the simulator's
        thread cannot hold the stream off for ten periods."""
        sys.setswitchinterval(min(sys.getswitchinterval(), 0.5e-3))
        listener = socket.socket(socket.AF_INET6 if ":" in self.host else socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            listener.bind((self.host, self.port))
        except OSError:
            listener.close()
            raise
        listener.listen(8)
        listener.setblocking(False)
        self._listener = listener
        self._thread = threading.Thread(target=self._run, name="haptic-stream", daemon=True)
        self._thread.start()
        return listener.getsockname()[:2]

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        for client in [*self._clients, *([self._listener] if self._listener else [])]:
            client.close()
        self._clients.clear()

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        deadline = time.monotonic()
        while not self._stop.is_set():
            try:
                self._accept()
                if self._clients:
                    self._send(b"".join(igtl.encode_message(igtl.Message(*message)) for message in force_messages(*self.force.now())))
                self.stats["periods"] += 1
            except Exception:  # a bug of ours must not end the stream (nor the trainer): logged
                log.exception("haptic stream period failed")
            deadline += period
            late = time.monotonic() - deadline
            if late > period:
                deadline = time.monotonic()  # fell behind (a busy machine): go on from now, never burst
            elif late < 0:
                time.sleep(-late)

    def _accept(self) -> None:
        assert self._listener is not None
        while True:
            try:
                client, peer = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            address = ipaddress.ip_address(peer[0].partition("%")[0])
            if address.version == 6 and address.ipv4_mapped is not None:
                address = address.ipv4_mapped
            if not any(address in network for network in self.allowed):
                self.stats["refused_peers"] += 1
                log.warning("haptic stream connection from %s refused: not in the allowed networks", address)
                client.close()
                continue
            client.setblocking(False)
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._clients[client] = bytearray()
            self.stats["clients"] += 1

    def _send(self, data: bytes) -> None:
        for client, unsent in list(self._clients.items()):
            if len(unsent) > _MAX_UNSENT_BYTES:
                self.stats["dropped"] += 1
            else:
                unsent += data
                self.stats["sent"] += 1
            try:
                written = client.send(unsent)
                del unsent[:written]
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:  # the client left
                del self._clients[client]
                with contextlib.suppress(OSError):
                    client.close()


def contact_of(states: list[dict]) -> dict | None:
    """What the stream follows of a tick's states (one per live session): the first session reaming
    with a whole-socket model (a haptic device serves one trainee), else None."""
    return next((state["reaming"]["contact"] for state in states if (state.get("reaming") or {}).get("contact")), None)
