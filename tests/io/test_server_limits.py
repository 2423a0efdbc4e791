"""What one client can cost the others: client slots held by idle sockets, invented device names,
odd device names, errors inside the server. Real sockets on 127.0.0.1; every wait is bounded."""

from __future__ import annotations

import contextlib
import json
import logging
import socket
import threading
import time

import pyigtl
import pytest
from igtl_helpers import is_closed, read_message, reamer_pose_mm, transform_message, wait_until

from thrsim.config import IgtlConfig
from thrsim.io import igtl
from thrsim.io.server import NAVIGATION_STATE

pytestmark = pytest.mark.timeout(60)


def status_of(message: igtl.Message) -> tuple[int, str, str]:
    assert message.type_name == "STATUS", message.type_name
    return igtl.unpack_status(message.content)


def served(sock: socket.socket) -> bool:
    sock.sendall(transform_message(reamer_pose_mm()))
    reply = read_message(sock)
    return reply.type_name == "STRING" and json.loads(igtl.unpack_string(reply.content))["inclination_deg"] is not None


def raw_tracker_round_trip(server, deadline_s: float) -> tuple[socket.socket, int]:
    """Connect and send a pose until a NavigationState comes back, as a tracker that reconnects
    would; returns the connected socket and how many connections it took."""
    attempts = 0
    deadline = time.monotonic() + deadline_s
    while time.monotonic() < deadline:
        attempts += 1
        sock = server.connect(timeout=2.0)
        try:
            sock.sendall(transform_message(reamer_pose_mm()))
            reply = read_message(sock)
            if reply.type_name == "STRING":
                return sock, attempts
            assert status_of(reply)[0] == igtl.STATUS_BUSY  # refused politely: retry
        except (ConnectionError, OSError):
            pass
        sock.close()
        time.sleep(0.1)
    pytest.fail(f"the tracker was not served within {deadline_s} s ({attempts} connection attempts)")


def test_idle_sockets_in_every_slot_do_not_lock_out_a_tracker(make_server):
    config = IgtlConfig(port=0)  # the defaults: 32 slots, idle timeout well under a minute
    assert config.idle_timeout_s < 60 and config.reclaim_after_s < config.idle_timeout_s
    server = make_server(config)
    with contextlib.ExitStack() as stack:
        idle = [stack.enter_context(server.connect()) for _ in range(config.max_clients)]
        assert wait_until(lambda: server.server.clients == config.max_clients)
        tracker, _ = raw_tracker_round_trip(server, deadline_s=10.0)
        stack.enter_context(tracker)
        # in because an idle socket's slot was reclaimed, not because an idle timeout ran out
        assert server.server.stats["reclaimed_slots"] >= 1 and server.server.stats["idle_timeouts"] == 0
        # a real OpenIGTLink client (pyigtl, which reconnects by itself) gets in too
        client = pyigtl.OpenIGTLinkClient("127.0.0.1", server.port)
        try:
            reply = None
            deadline = time.monotonic() + 10.0
            while reply is None and time.monotonic() < deadline:
                client.send_message(pyigtl.TransformMessage(reamer_pose_mm(), device_name="ReamerToReference"), wait=False)
                reply = client.wait_for_message(NAVIGATION_STATE, timeout=1.0)
            assert reply is not None, "pyigtl was never served"
            assert json.loads(reply.string)["inclination_deg"] == pytest.approx(40.0, abs=1e-3)
        finally:
            client.stop()
        assert served(tracker)
        # the sockets that lost their slot were told why and closed
        told = [code for code in map(_closed_with_status, idle) if code is not None]
        assert told and set(told) == {igtl.STATUS_TIMEOUT}
        assert server.server.clients <= config.max_clients


def _closed_with_status(sock: socket.socket) -> int | None:
    sock.settimeout(0.05)
    try:
        message = read_message(sock)
    except (OSError, ConnectionError):
        return None
    return status_of(message)[0]


def test_idle_connection_is_closed_after_the_idle_timeout_and_a_talking_one_is_not(make_server):
    server = make_server(IgtlConfig(port=0, idle_timeout_s=0.5))
    with server.connect() as silent, server.connect() as talking:
        deadline = time.monotonic() + 1.5  # three idle timeouts
        while time.monotonic() < deadline:
            assert served(talking)
            time.sleep(0.05)
        silent.settimeout(5)
        code, name, _ = status_of(read_message(silent))
        assert (code, name) == (igtl.STATUS_TIMEOUT, "IdleTimeout")
        assert is_closed(silent)
        assert served(talking)
    assert server.server.stats["idle_timeouts"] == 1


def test_a_full_server_of_talking_clients_refuses_a_newcomer(make_server):
    server = make_server(IgtlConfig(port=0, max_clients=2, reclaim_after_s=0.0))  # clients that spoke keep their slot
    with server.connect() as first, server.connect() as second:
        assert served(first) and served(second)
        with server.connect() as third:
            assert status_of(read_message(third))[0] == igtl.STATUS_BUSY
            assert is_closed(third)
        assert served(first) and served(second)
    assert server.server.stats["rejected_connections"] == 1 and server.server.stats["reclaimed_slots"] == 0


def test_invented_device_names_cannot_grow_the_session(make_server):
    config = IgtlConfig(port=0, max_other_devices=8)
    server = make_server(config)
    names = [f"Invented{k:05d}" for k in range(2000)]
    with server.connect(timeout=10) as sock:
        replies = []
        for start in range(0, len(names), 100):  # pipelined, 100 at a time
            sock.sendall(b"".join(transform_message(reamer_pose_mm(), device=n) for n in names[start : start + 100]))
            replies += [read_message(sock) for _ in range(100)]
        refused = [m for m in replies if m.type_name == "STATUS"]
        assert len(refused) == 2000 - 8
        assert all(status_of(m)[:2] == (igtl.STATUS_CONFIGURATION_ERROR, "UnknownDevice") for m in refused)
        assert refused[0].device_name == names[8]
        assert served(sock)  # a known device name still counts
    session = server.server.tracker
    assert len(session.poses) <= len(config.known_devices) + config.max_other_devices
    assert set(session.poses) == set(names[:8]) | {"ReamerToReference"}
    assert server.server.stats["unknown_devices"] == 2000 - 8


def test_configured_device_names_are_accepted(make_server):
    server = make_server(IgtlConfig(port=0, known_devices=("CupImpactor",), max_other_devices=0))
    with server.connect() as sock:
        sock.sendall(transform_message(reamer_pose_mm(), device="CupImpactor"))
        assert read_message(sock).type_name == "STRING"
        sock.sendall(transform_message(reamer_pose_mm(), device="ReamerToReference"))
        assert status_of(read_message(sock))[1] == "UnknownDevice"
    assert set(server.server.tracker.poses) == {"CupImpactor"}


def test_a_non_ascii_device_name_on_a_bad_crc_gets_its_status(nav_server):
    name = "\u00e9" * 20  # 20 bytes in latin-1, 40 in UTF-8
    raw = bytearray(igtl.encode_message(igtl.Message("TRANSFORM", name, igtl.pack_transform(reamer_pose_mm()))))
    assert bytes(raw[14:34]) == b"\xe9" * 20
    raw[-1] ^= 1  # bad CRC, framing intact
    with nav_server.connect() as sock:
        sock.sendall(bytes(raw))
        reply = read_message(sock)
        assert status_of(reply)[0] == igtl.STATUS_CHECKSUM_ERROR
        assert reply.device_name == name  # the sender's own name, byte for byte
        assert served(sock)
    assert nav_server.server.stats["internal_errors"] == 0


def test_an_error_inside_the_server_is_answered_and_stays_in_its_connection(nav_server, monkeypatch):
    session = nav_server.server.tracker
    real_state = session.state
    calls = []

    def fails_once(time_s):
        calls.append(time_s)
        if len(calls) == 1:
            raise RuntimeError("a bug in the state")
        return real_state(time_s)

    monkeypatch.setattr(session, "state", fails_once)
    with nav_server.connect() as sock, nav_server.connect() as bystander:
        sock.sendall(transform_message(reamer_pose_mm()))
        code, name, text = status_of(read_message(sock))
        assert (code, name) == (igtl.STATUS_UNKNOWN_ERROR, "InternalError") and "a bug in the state" in text
        assert served(sock) and served(bystander)
    assert nav_server.server.stats["internal_errors"] == 1


def test_the_trainers_device_names_are_known_to_the_server():
    from thrsim.app.navigation import DEVICES

    assert set(DEVICES) <= set(IgtlConfig().known_devices)


class _Squatters:
    """``count`` connections that each send one message every ``period_s`` that the trainer does not
    use (a STATUS, or a pose under an invented device name), reconnecting whenever they lose their
    slot: what a peer holding slots without tracking anything does. Runs in a thread until stopped."""

    def __init__(self, server, count: int, period_s: float):
        self.server, self.period_s = server, period_s
        self.messages = [
            igtl.encode_message(igtl.Message("STATUS", f"Squatter{k}", igtl.pack_status(1, "OK", "here")))
            if k % 2
            else transform_message(reamer_pose_mm(), device=f"Squatter{k}")
            for k in range(count)
        ]
        self.sockets = [self._join(message) for message in self.messages]
        self.reconnections = 0
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._talk, daemon=True)
        self.thread.start()

    def _join(self, message: bytes) -> socket.socket:
        sock = self.server.connect()
        sock.sendall(message)
        sock.setblocking(False)
        return sock

    def _talk(self) -> None:
        while not self.stopping.wait(self.period_s):
            for k, sock in enumerate(self.sockets):
                try:
                    while sock.recv(65536):  # the replies, if any; b"" once the server closed it
                        pass
                    closed = True
                except BlockingIOError:
                    closed = False
                except OSError:
                    closed = True
                if closed:
                    sock.close()
                    self.sockets[k] = self._join(self.messages[k])
                    self.reconnections += 1
                else:
                    with contextlib.suppress(OSError):
                        sock.sendall(self.messages[k])

    def stop(self) -> None:
        self.stopping.set()
        self.thread.join(5)
        for sock in self.sockets:
            sock.close()


def test_squatters_that_talk_without_tracking_do_not_lock_out_a_tracker(make_server):
    config = IgtlConfig(port=0)  # the defaults: 32 slots
    server = make_server(config)
    squatters = _Squatters(server, config.max_clients, period_s=2.0)
    try:
        assert wait_until(lambda: server.server.clients == config.max_clients and server.server.stats["messages"] >= config.max_clients)
        time.sleep(config.reclaim_after_s)  # every squatter has had its chance to earn its slot
        started = time.monotonic()
        with server.connect() as tracker:
            tracker.sendall(transform_message(reamer_pose_mm()))
            reply = read_message(tracker)
            assert reply.type_name == "STRING", status_of(reply)
            assert time.monotonic() - started < 1.0
            # the squatters keep talking and reconnecting; a tracker that streams keeps its slot
            deadline = time.monotonic() + 3 * squatters.period_s
            while time.monotonic() < deadline:
                assert served(tracker)
                time.sleep(0.1)
        assert squatters.reconnections >= 1 and server.server.clients <= config.max_clients
    finally:
        squatters.stop()


def test_a_client_that_stopped_tracking_gives_way_to_a_newcomer(make_server):
    server = make_server(IgtlConfig(port=0, max_clients=2, reclaim_after_s=0.0, idle_timeout_s=1.0))
    chatter = igtl.encode_message(igtl.Message("STATUS", "Chatter", igtl.pack_status(1, "OK", "still here")))
    with server.connect() as stopped, server.connect() as streaming:
        assert served(stopped) and served(streaming)
        for _ in range(8):  # 1.2 s: talking (so not idle) but tracking nothing, while the other streams
            stopped.sendall(chatter)
            assert served(streaming)
            time.sleep(0.15)
        with server.connect() as newcomer:
            assert served(newcomer)
            assert status_of(read_message(stopped))[:2] == (igtl.STATUS_TIMEOUT, "SlotReclaimed")
            assert is_closed(stopped)
            assert served(streaming)
    assert server.server.stats["reclaimed_slots"] == 1 and server.server.stats["idle_timeouts"] == 0


def _closed_without_a_word(sock: socket.socket) -> bool:
    """The peer closed (or reset, having left what was sent unread) and sent nothing."""
    sock.settimeout(5)
    try:
        return sock.recv(65536) == b""
    except ConnectionResetError:
        return True


def test_peers_outside_the_allowed_networks_are_closed_at_once(make_server, caplog):
    server = make_server(IgtlConfig(port=0, allowed_peers=("127.0.0.2/32",)))
    with caplog.at_level(logging.WARNING, logger="thrsim.io.server"):
        for _ in range(3):
            with server.connect() as outsider:  # from 127.0.0.1
                outsider.sendall(transform_message(reamer_pose_mm()))
                assert _closed_without_a_word(outsider)
        assert wait_until(lambda: server.server.stats["refused_peers"] == 3)
    refusals = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    assert refusals == ["OpenIGTLink connection from 127.0.0.1 refused: not in the allowed networks"] * 3
    with socket.create_connection((server.host, server.port), timeout=5, source_address=("127.0.0.2", 0)) as insider:
        assert served(insider)
    assert server.server.tracker.poses.keys() == {"ReamerToReference"} and server.server.stats["transforms"] == 1
