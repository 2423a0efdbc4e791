"""The force a haptic device renders, streamed far faster than the simulator's frames (``thrsim serve --haptic-port``).

A HIPS-style haptic loop runs at 1 kHz and needs an answer within a millisecond; the simulator
steps a frame each 1/60 s. Between frames :class:`ContactForce` evaluates the reaction law the
whole-socket model predicted for the next frame at the newest push, as that frame records it
(:func:`thrsim.learn.reaction_feed.felt_at_push`: the law's R = A + B·v at the balanced feed, the
push itself at a stall): so a frame records what the stream sent before it, and a change of push
is felt within one period instead of a frame. Nothing
reams (paused, hidden, a patch model): zero. :class:`HapticStream` sends the pair of SENSORs of
:mod:`thrsim.io.feedback` from a process of its own (the simulator's thread holds this one's
interpreter lock for milliseconds) once a period; a late wake sends what it owes, up to
:data:`CATCH_UP_S` of it: a client renders the newest pair it has read.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import multiprocessing
import os
import socket
import time

import numpy as np

from thrsim.io import igtl
from thrsim.io.feedback import force_messages
from thrsim.learn.reaction_feed import felt_at_push

log = logging.getLogger(__name__)

#: a client holding this much unsent (it does not read) misses messages until it has read them
_MAX_UNSENT_BYTES = 64 * 1024
#: periods the stream wakes late for are sent at once, each pair the force then, up to this much of
#: them (a scheduler's late wake on a loaded machine is a few ms); beyond, it goes on from now
CATCH_UP_S = 0.010
_SPAWN = multiprocessing.get_context("spawn")  # a fresh interpreter: never a fork of the server's threads
# the shared figures: whether a law is followed, A, B, A_torque, B_torque (N, N·s/m, N·m, N·m·s/m),
# the hold's damping c (N·s/m), the push with the law (N), a sensor's newer push (N), and whether it is newer
_ACTIVE, _LAW, _DAMPING, _FORCE, _SENSOR, _SENSOR_NEWER, _FIGURES = 0, slice(1, 5), 5, 6, 7, 8, 9


class ContactForce:
    """The fast contact model: the latest law and push in memory shared with the stream's process
    (written and read under its lock, so a reader never sees half an update)."""

    def __init__(self) -> None:
        self.shared = _SPAWN.Array("d", _FIGURES)

    def follow(self, contact: dict | None) -> None:
        """A trainer step's ``contact`` (its law, the hold's damping and the push), or None when nothing reams."""
        with self.shared.get_lock():
            self.shared[_ACTIVE] = 0.0 if contact is None else 1.0
            if contact is not None:
                self.shared[_LAW] = [float(v) for v in contact["law"]]
                self.shared[_DAMPING], self.shared[_FORCE] = float(contact["damping_n_s_m"]), float(contact["force_n"])
            self.shared[_SENSOR_NEWER] = 0.0  # the step read every reading before it

    def push(self, newton: float) -> None:
        """A force sensor's reading, felt before the next frame reads it."""
        with self.shared.get_lock():
            self.shared[_SENSOR], self.shared[_SENSOR_NEWER] = float(newton), 1.0

    def now(self) -> tuple[float, float]:
        """(reaction N, motor torque N·m) at the newest push."""
        with self.shared.get_lock():
            figures = self.shared[:]
        if not figures[_ACTIVE]:
            return 0.0, 0.0
        force = figures[_SENSOR] if figures[_SENSOR_NEWER] else figures[_FORCE]
        return felt_at_push(np.asarray(figures[_LAW]), force, figures[_DAMPING])


class HapticStream:
    """An OpenIGTLink server, in a process of its own, that only sends: ``ReamerReaction`` and
    ``ReamerTorque`` SENSORs every ``1/rate_hz`` s to each client from ``allowed`` networks (others
    are closed at once)."""

    def __init__(self, host: str, port: int, rate_hz: float, allowed: tuple[str, ...], force: ContactForce):
        self.host, self.port, self.rate_hz, self.allowed, self.force = host, port, rate_hz, allowed, force
        self._stop = _SPAWN.Event()
        self._process: multiprocessing.process.BaseProcess | None = None

    def start(self, timeout_s: float = 60.0) -> tuple[str, int]:
        """Start the stream's process; the (host, port) it listens on (the OS picks a port for 0), or
        OSError where it cannot listen."""
        reader, writer = _SPAWN.Pipe(duplex=False)
        self._process = _SPAWN.Process(
            target=_serve,
            args=(self.host, self.port, self.rate_hz, self.allowed, self.force, self._stop, writer, os.getpid()),
            daemon=True,
        )
        self._process.start()
        writer.close()
        if not reader.poll(timeout_s):
            self.close()
            raise OSError(f"the haptic stream did not start in {timeout_s:g} s")
        answer = reader.recv()
        if isinstance(answer, str):
            self.close()
            raise OSError(answer)
        return answer

    def close(self) -> None:
        self._stop.set()
        if self._process is not None:
            self._process.join(5)
            if self._process.is_alive():
                self._process.terminate()
                self._process.join(5)


def _serve(host: str, port: int, rate_hz: float, allowed: tuple[str, ...], force: ContactForce, stop, started, server_pid: int) -> None:
    """The stream's process: listen, say where (or why not) through ``started``, send until ``stop``
    or until the server is gone (killed, it could not say stop)."""
    listener = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        listener.bind((host, port))
    except OSError as error:
        started.send(error.strerror or str(error))
        listener.close()
        return
    listener.listen(8)
    listener.setblocking(False)
    started.send(listener.getsockname()[:2])
    _Sender(listener, rate_hz, tuple(ipaddress.ip_network(network) for network in allowed), force).run(stop, server_pid)


class _Sender:
    """The stream's loop: accept admitted clients, send each period's pair to every one."""

    def __init__(self, listener: socket.socket, rate_hz: float, allowed, force: ContactForce):
        self.listener, self.rate_hz, self.allowed, self.force = listener, rate_hz, allowed, force
        self._clients: dict[socket.socket, bytearray] = {}

    def run(self, stop, server_pid: int) -> None:
        period = 1.0 / self.rate_hz
        most_owed = max(1, round(CATCH_UP_S / period))
        due = time.monotonic()  # when the next period's pair is due
        while not stop.is_set() and os.getppid() == server_pid:
            owed = int((time.monotonic() - due) / period) + 1
            if owed > most_owed:  # asleep far longer than a period (a busy machine): go on from now
                due += (owed - most_owed) * period
                owed = most_owed
            try:
                self._accept()
                if self._clients:
                    pair = b"".join(igtl.encode_message(igtl.Message(*message)) for message in force_messages(*self.force.now()))
                    self._send(pair * owed)
            except Exception:  # a bug of ours must not end the stream (nor the trainer): logged
                log.exception("haptic stream period failed")
            due += owed * period
            time.sleep(max(0.0, due - time.monotonic()))
        for client in [*self._clients, self.listener]:
            client.close()

    def _accept(self) -> None:
        while True:
            try:
                client, peer = self.listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            address = ipaddress.ip_address(peer[0].partition("%")[0])
            if address.version == 6 and address.ipv4_mapped is not None:
                address = address.ipv4_mapped
            if not any(address in network for network in self.allowed):
                log.warning("haptic stream connection from %s refused: not in the allowed networks", address)
                client.close()
                continue
            client.setblocking(False)
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._clients[client] = bytearray()

    def _send(self, data: bytes) -> None:
        for client, unsent in list(self._clients.items()):
            if len(unsent) <= _MAX_UNSENT_BYTES:
                unsent += data
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
