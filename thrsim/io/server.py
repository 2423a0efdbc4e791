"""Asyncio OpenIGTLink server: tracker poses and force in, NavigationState out.

Each connection has its own task, so a stalled or hostile peer only ever costs its own
connection: any error while serving it (ours included) ends at that connection, with a STATUS
reply where the stream allows one, and one warning line in the log naming the peer and why
(a traceback only for a bug of ours). Large bodies are checksummed in a worker thread, so the
event loop never waits on computation. What each message gets, and who keeps a slot:
:class:`IgtlServer`.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import logging
import time
from collections.abc import Callable
from typing import cast

from thrsim.config import IgtlConfig
from thrsim.errors import ThrsimInputError
from thrsim.io import igtl
from thrsim.nav.tracker_state import TrackerState

log = logging.getLogger(__name__)

NAVIGATION_STATE = "NavigationState"
# Above this a pure-Python CRC takes milliseconds: hand it to a thread.
_CRC_IN_THREAD_BYTES = 64 * 1024


class _Connection:
    """One peer: its writer and the header version to answer in."""

    def __init__(self, server: IgtlServer, writer: asyncio.StreamWriter):
        self.server = server
        self.writer = writer
        peer = writer.get_extra_info("peername")
        self.peer = f"{peer[0]}:{peer[1]}" if peer else "unknown peer"
        self.handler_task = cast(asyncio.Task, asyncio.current_task())  # made in its handler's task: never None
        self.connected_at = asyncio.get_running_loop().time()
        self.earned_at: float | None = None  # when it last sent a pose or force the trainer uses (loop time)
        self.version = 1
        self.send_lock = asyncio.Lock()
        self.fed_at: float | None = None  # when feedback was last written to it (loop time)

    def close(self) -> None:
        self.writer.close()

    async def send(self, type_name: str, device: str, content: bytes) -> None:
        data = igtl.encode_message(igtl.Message(type_name, device, content, version=self.version))
        async with self.send_lock:
            self.writer.write(data)
            await asyncio.wait_for(self.writer.drain(), self.server.config.io_timeout_s)
        self.server.stats["sent"] += 1

    async def send_status(self, code: int, name: str, text: str, device: str = "") -> None:
        await self.send("STATUS", device, igtl.pack_status(code, name, text[:200]))

    def say_goodbye(self, code: int, name: str, text: str) -> None:
        """A last STATUS, without waiting on a peer that may not read, then close (the transport
        flushes what it can)."""
        if not self.writer.is_closing():
            with contextlib.suppress(Exception):
                self.writer.write(
                    igtl.encode_message(igtl.Message("STATUS", "", igtl.pack_status(code, name, text[:200]), version=self.version))
                )
        self.close()


class IgtlServer:
    """Serve many OpenIGTLink clients at once.

    Per message:

    * TRANSFORM (``ReamerToReference``, ``ReferenceToTracker``, ...; translation in mm) and SENSOR
      (force in N) update the shared :class:`~thrsim.nav.tracker_state.TrackerState`, and the sender
      gets a STRING message named ``NavigationState`` with the state as JSON;
    * a bad CRC-64 or unusable content gets a STATUS reply (code 9 checksum error, 10
      configuration error) and the connection goes on: its framing is intact;
    * a well-formed message of a type the trainer does not use is counted and ignored;
    * a TRANSFORM under a device name beyond the known ones and ``max_other_devices`` others gets a
      STATUS reply (10) and is not stored: the shared tracker state stays bounded;
    * an unsupported header version, a non-ASCII type, a body above ``max_body_bytes`` or a message
      that stalls past ``io_timeout_s`` means the stream cannot be resynchronised: a STATUS reply
      where possible, then that connection (only) is closed.

    Peers: a connection from an address outside ``allowed_peers`` (loopback alone by default) is
    closed at once, with one log line and no reply.

    Feedback (``feedback`` on, :mod:`thrsim.io.feedback`): :meth:`broadcast` writes the trainer's
    events and simulated reamer to every connection, without waiting on any: a connection with more
    than ``max_body_bytes`` still unsent (a peer that does not read) misses them, counted.

    Slots: at most ``max_clients`` connections. One that sends nothing for ``idle_timeout_s`` gets a
    STATUS (7, time out) and is closed, unless feedback is on and it has read all the feedback sent
    it in that time (a viewer, such as 3D Slicer showing the simulated reamer, need not send). A
    client earns its slot by sending what the trainer uses: a
    pose of a known device or a force reading. When every slot is taken, a newcomer takes the slot
    of the oldest connection that has earned nothing in the ``reclaim_after_s`` since it connected,
    else of the one whose last useful message is oldest, if older than ``idle_timeout_s`` (that
    one gets STATUS 7); with neither, the newcomer gets STATUS 6 (busy) and is closed. So sockets that
    stay idle, or talk without tracking anything, cannot lock a tracker out, and a tracker keeps
    its slot through a pause (an occluded tool) shorter than the idle timeout.
    """

    def __init__(
        self,
        config: IgtlConfig = IgtlConfig(),
        tracker: TrackerState | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.config = config
        self.tracker = tracker if tracker is not None else TrackerState(stale_after_s=config.stale_pose_s)
        self.clock = clock
        self.stats = dict.fromkeys(
            ("connections", "rejected_connections", "messages", "transforms", "sensors", "replies", "sent", "bad_crc",
             "bad_content", "unknown_type", "oversize", "protocol_errors", "timeouts"),
            0,
        )  # fmt: skip
        self.stats.update(
            dict.fromkeys(("idle_timeouts", "reclaimed_slots", "unknown_devices", "internal_errors", "refused_peers", "truncated"), 0)
        )
        self.stats.update(dict.fromkeys(("feedback_sent", "feedback_dropped"), 0))
        self._connections: set[_Connection] = set()
        self._handlers: set[asyncio.Task] = set()  # every connection's task, reclaimed ones included
        self._other_devices: set[str] = set()  # TRANSFORM names beyond config.known_devices, bounded
        self._server: asyncio.Server | None = None

    @property
    def clients(self) -> int:
        return len(self._connections)

    async def start(self) -> tuple[str, int]:
        """Listen; returns the bound (host, port) — the port is chosen by the OS when 0."""
        self._server = await asyncio.start_server(self._handle, self.config.host, self.config.port)
        host, port = self._server.sockets[0].getsockname()[:2]
        return host, port

    async def close(self) -> None:
        """Stop listening and end every connection, waiting for their tasks to finish."""
        if self._server is None:
            return
        self._server.close()
        tasks = list(self._handlers)
        for connection in list(self._connections):
            if connection.writer.transport.get_write_buffer_size() > 0:
                connection.writer.transport.abort()  # a peer not reading what it was sent would hold the close open
            else:
                connection.close()  # the handler's next read sees end of stream and returns
        if tasks:
            _, stuck = await asyncio.wait(tasks, timeout=self.config.io_timeout_s)
            for task in stuck:
                task.cancel()
        await self._server.wait_closed()

    def snapshot(self) -> dict:
        """Navigation state, client count and counters, for logs."""
        return {"state": self.tracker.state(self.clock()), "clients": self.clients, "stats": dict(self.stats)}

    def broadcast(self, messages: list[tuple[str, str, bytes]]) -> None:
        """Write ``messages`` (type, device name, content) to every connection, in its header version,
        without waiting (on the event loop): a connection holding more than ``max_body_bytes`` unsent
        misses them (``feedback_dropped``), so a peer that does not read neither slows the others nor
        grows memory. Only admitted peers (``allowed_peers``) have connections."""
        if not messages:
            return
        now = asyncio.get_running_loop().time()
        encoded: dict[int, bytes] = {}  # header version → the messages, checksummed once
        for connection in list(self._connections):
            if connection.writer.is_closing():
                continue
            if connection.writer.transport.get_write_buffer_size() > self.config.max_body_bytes:
                self.stats["feedback_dropped"] += len(messages)
                continue
            if connection.version not in encoded:
                encoded[connection.version] = b"".join(
                    igtl.encode_message(igtl.Message(type_name, device, content, version=connection.version))
                    for type_name, device, content in messages
                )
            connection.writer.write(encoded[connection.version])
            connection.fed_at = now
            self.stats["feedback_sent"] += len(messages)

    def _reads_feedback(self, connection: _Connection) -> bool:
        """With feedback on: whether the connection was fed within ``idle_timeout_s`` and its peer read it all."""
        if not self.config.feedback or connection.fed_at is None:
            return False
        recent = asyncio.get_running_loop().time() - connection.fed_at < self.config.idle_timeout_s
        return recent and connection.writer.transport.get_write_buffer_size() == 0

    def _peer_allowed(self, writer: asyncio.StreamWriter) -> bool:
        """Whether the peer's address lies in ``allowed_peers``; refused peers are logged, one line each."""
        peer = writer.get_extra_info("peername")
        address = ipaddress.ip_address(peer[0].partition("%")[0])  # without an IPv6 scope
        if address.version == 6 and address.ipv4_mapped is not None:
            address = address.ipv4_mapped
        if any(address in network for network in self.config.allowed_peers):
            return True
        self.stats["refused_peers"] += 1
        log.warning("OpenIGTLink connection from %s refused: not in the allowed networks", address)
        return False

    def _take_slot(self, connection: _Connection) -> bool:
        """Admit ``connection``; when full, reclaim the slot of a connection that has not earned it
        (see the class docstring), or refuse the newcomer."""
        if len(self._connections) >= self.config.max_clients:
            now = asyncio.get_running_loop().time()
            never_earned = [c for c in self._connections if c.earned_at is None and now - c.connected_at >= self.config.reclaim_after_s]
            gone_stale = [
                (c.earned_at, c) for c in self._connections if c.earned_at is not None and now - c.earned_at >= self.config.idle_timeout_s
            ]
            if never_earned:
                victim = min(never_earned, key=lambda c: c.connected_at)
                why = "no pose or force the trainer uses since connecting, and every client slot was wanted"
            elif gone_stale:
                earned_at, victim = min(gone_stale, key=lambda stale: stale[0])
                why = f"no pose or force the trainer uses for {now - earned_at:.1f} s, and every client slot was wanted"
            else:
                self.stats["rejected_connections"] += 1
                connection.say_goodbye(igtl.STATUS_BUSY, "ServerFull", f"all {self.config.max_clients} client slots are in use")
                return False
            self._connections.discard(victim)
            self.stats["reclaimed_slots"] += 1
            victim.say_goodbye(igtl.STATUS_TIMEOUT, "SlotReclaimed", why)
        self._connections.add(connection)
        self.stats["connections"] += 1
        return True

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if not self._peer_allowed(writer):
            writer.close()
            return
        connection = _Connection(self, writer)
        if not self._take_slot(connection):
            return
        self._handlers.add(connection.handler_task)
        try:
            while await self._serve_one(reader, connection):
                pass
        except (asyncio.IncompleteReadError, ConnectionError):
            pass  # peer went away between messages (mid-message is logged where it is read)
        except TimeoutError:
            self.stats["timeouts"] += 1
            _refused(connection, f"a message or a reply took longer than {self.config.io_timeout_s:g} s; connection closed")
            connection.say_goodbye(igtl.STATUS_TIMEOUT, "Timeout", f"a message or a reply took longer than {self.config.io_timeout_s:g} s")
        except Exception as error:  # a bug of ours or a peer we did not foresee: this connection only
            self.stats["internal_errors"] += 1
            log.exception("OpenIGTLink connection failed")
            connection.say_goodbye(igtl.STATUS_UNKNOWN_ERROR, "InternalError", f"{type(error).__name__}: {error}")
        finally:
            self._connections.discard(connection)
            self._handlers.discard(connection.handler_task)
            connection.close()

    async def _serve_one(self, reader: asyncio.StreamReader, connection: _Connection) -> bool:
        """Read and act on one message; False when the connection must close."""
        try:
            first = await asyncio.wait_for(reader.readexactly(1), self.config.idle_timeout_s)
        except TimeoutError:
            if self._reads_feedback(connection):
                return True  # a viewer reading the feedback: not idle
            self.stats["idle_timeouts"] += 1
            connection.say_goodbye(igtl.STATUS_TIMEOUT, "IdleTimeout", f"no message for {self.config.idle_timeout_s:g} s")
            return False
        rest = await self._read_rest(reader, igtl.HEADER_SIZE - 1, connection, "header")
        if rest is None:
            return False
        try:
            header = igtl.parse_header(first + rest)
        except igtl.IgtlProtocolError as error:
            self.stats["protocol_errors"] += 1
            _refused(connection, f"{error}; connection closed")
            await connection.send_status(error.status_code, "ProtocolError", str(error))
            return False
        if header.body_size > self.config.max_body_bytes:
            self.stats["oversize"] += 1
            _refused(connection, f"body of {header.body_size} bytes exceeds {self.config.max_body_bytes}; connection closed")
            await connection.send_status(
                igtl.STATUS_OVERFLOW,
                "BodyTooLarge",
                f"body of {header.body_size} bytes exceeds {self.config.max_body_bytes}",
                header.device_name,
            )
            return False
        body = await self._read_rest(reader, header.body_size, connection, f"{header.type_name} body")
        if body is None:
            return False
        self.stats["messages"] += 1
        # the whole message is in: the stream is still framed, so whatever goes wrong now is
        # answered with a STATUS and the connection goes on
        try:
            crc = await asyncio.to_thread(igtl.crc64, body) if len(body) > _CRC_IN_THREAD_BYTES else igtl.crc64(body)
            try:
                message = igtl.decode_body(header, body, crc)
            except igtl.IgtlProtocolError as error:
                self.stats["bad_crc" if error.status_code == igtl.STATUS_CHECKSUM_ERROR else "bad_content"] += 1
                _refused(connection, f"{error}; connection closed" if error.fatal else str(error))
                await connection.send_status(error.status_code, "BadMessage", str(error), header.device_name)
                return not error.fatal
            connection.version = message.version
            await self._dispatch(message, connection)
        except (TimeoutError, ConnectionError):
            raise  # the peer is gone or not reading: the connection ends (see _handle)
        except Exception as error:  # noqa: BLE001 - one message's failure is that message's STATUS
            self.stats["internal_errors"] += 1
            log.exception("serving a %s message failed", header.type_name)
            await connection.send_status(igtl.STATUS_UNKNOWN_ERROR, "InternalError", f"{type(error).__name__}: {error}", header.device_name)
        return True

    async def _read_rest(self, reader: asyncio.StreamReader, size: int, connection: _Connection, what: str) -> bytes | None:
        """The next ``size`` bytes of a message begun, or None (logged) when the peer closes before they all come."""
        try:
            return await asyncio.wait_for(reader.readexactly(size), self.config.io_timeout_s)
        except asyncio.IncompleteReadError as error:
            self.stats["truncated"] += 1
            _refused(connection, f"closed after {len(error.partial)} of the {size} bytes of the {what} still to come")
            return None

    def _device_accepted(self, device: str) -> bool:
        """A known device, one of the other names already taken, or a new one while there is room."""
        if device in self.config.known_devices or device in self._other_devices:
            return True
        if len(self._other_devices) < self.config.max_other_devices:
            self._other_devices.add(device)
            return True
        return False

    async def _dispatch(self, message: igtl.Message, connection: _Connection) -> None:
        now = self.clock()
        try:
            if message.type_name == "TRANSFORM":
                pose = igtl.unpack_transform(message.content)
                if not self._device_accepted(message.device_name):
                    self.stats["unknown_devices"] += 1
                    _refused(connection, f"TRANSFORM of unknown device {message.device_name!r} ignored: no room for other names")
                    await connection.send_status(
                        igtl.STATUS_CONFIGURATION_ERROR, "UnknownDevice",
                        f"device {message.device_name!r} is not one of {', '.join(self.config.known_devices)} and the "
                        f"{self.config.max_other_devices} other name(s) allowed are taken; pose ignored", message.device_name,
                    )  # fmt: skip
                    return
                self.tracker.update_pose(message.device_name, pose, now)
                self.stats["transforms"] += 1
                if message.device_name in self.config.known_devices:
                    connection.earned_at = asyncio.get_running_loop().time()
            elif message.type_name == "SENSOR":
                values, unit = igtl.unpack_sensor(message.content)
                if unit not in (0, igtl.UNIT_NEWTON):
                    raise igtl.IgtlProtocolError(f"SENSOR unit {unit:#x} is not newton", igtl.STATUS_CONFIGURATION_ERROR)
                self.tracker.update_force(values, now)
                self.stats["sensors"] += 1
                connection.earned_at = asyncio.get_running_loop().time()
            else:
                self.stats["unknown_type"] += 1
                log.debug("ignoring %s message %r", message.type_name, message.device_name)
                return
        except (igtl.IgtlProtocolError, ThrsimInputError) as error:
            self.stats["bad_content"] += 1
            _refused(connection, f"{message.type_name}: {error}")
            await connection.send_status(igtl.STATUS_CONFIGURATION_ERROR, "BadContent", str(error), message.device_name)
            return
        state = self.tracker.state(now)
        await connection.send("STRING", NAVIGATION_STATE, igtl.pack_string(json.dumps(state, allow_nan=False)))
        self.stats["replies"] += 1


def _refused(connection: _Connection, why: str) -> None:
    """One warning line for one bad message: the peer and why (a device name's line breaks escaped,
    so a peer cannot split or forge log lines)."""
    log.warning("OpenIGTLink message from %s refused: %s", connection.peer, why.replace("\r", "\\r").replace("\n", "\\n"))
