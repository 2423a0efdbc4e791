"""Property-based fuzz of the OpenIGTLink codec and listener (issue 27, item 5).

Codec: any bytes, a valid message truncated, extended or with a field rewritten (version, type,
body size, CRC, a byte anywhere), NaN and infinite transforms and any device name either decode
to a well-formed message or raise :class:`~thrsim.io.igtl.IgtlProtocolError`, never another
exception, and without reading past what they were given (no hang). Listener: random streams of
valid and malformed messages over a real socket on 127.0.0.1 cost one warning line per bad
message, naming the peer, never a traceback, and the listener serves a tracker after each.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from igtl_helpers import RunningServer, read_message, reamer_pose_mm, transform_message

from thrsim.config import KNOWN_TRACKER_DEVICES, IgtlConfig
from thrsim.errors import ThrsimInputError
from thrsim.io import igtl
from thrsim.io.server import NAVIGATION_STATE, IgtlServer
from thrsim.nav.tracker_state import TrackerState

pytestmark = pytest.mark.timeout(180)

UNPACKERS = (igtl.unpack_transform, igtl.unpack_sensor, igtl.unpack_string, igtl.unpack_status)
IGNORED_TYPES = ("STRING", "STATUS", "POSITION", "IMAGE", "GET_STATUS", "POINT")

device_names = st.binary(max_size=20).map(lambda raw: raw.replace(b"\0", b"").decode("latin-1"))
type_names = st.sampled_from(("TRANSFORM", "SENSOR", *IGNORED_TYPES)) | st.text(
    st.characters(min_codepoint=0x21, max_codepoint=0x7E), min_size=1, max_size=12
)
any_float32 = st.floats(width=32)  # NaN and ±inf included
transform_contents = st.lists(any_float32, min_size=12, max_size=12).map(lambda values: struct.pack(">12f", *values))
sensor_contents = st.lists(st.floats(), min_size=1, max_size=8).map(igtl.pack_sensor)
contents = transform_contents | sensor_contents | st.binary(max_size=200)


@st.composite
def messages(draw) -> igtl.Message:
    version = draw(st.sampled_from((1, 2)))
    metadata = draw(st.dictionaries(st.text(max_size=8), st.text(max_size=16), max_size=3)) if version == 2 else {}
    return igtl.Message(
        draw(type_names),
        draw(device_names),
        draw(contents),
        timestamp=draw(st.floats(0, 2**31, allow_subnormal=False)),
        version=version,
        metadata=metadata,
        message_id=draw(st.integers(0, 2**32 - 1)),
    )


def decode(raw: bytes) -> igtl.Message:
    """What the listener does with bytes once framed: header, then the body it declares (or what came of it)."""
    header = igtl.parse_header(raw[: igtl.HEADER_SIZE])
    return igtl.decode_body(header, raw[igtl.HEADER_SIZE : igtl.HEADER_SIZE + header.body_size])


def assert_well_formed(message: igtl.Message) -> None:
    assert message.version in igtl.SUPPORTED_VERSIONS
    assert 1 <= len(message.type_name) <= 12 and message.type_name.isascii() and message.type_name.isprintable()
    assert len(igtl.encode_device_name(message.device_name)) <= 20
    assert isinstance(message.content, bytes) and all(isinstance(k, str) and isinstance(v, str) for k, v in message.metadata.items())
    for unpack in UNPACKERS:
        with contextlib.suppress(igtl.IgtlProtocolError):
            unpack(message.content)


@settings(max_examples=200)
@given(message=messages())
def test_every_message_decodes_to_itself(message):
    decoded = decode(igtl.encode_message(message))
    assert (decoded.type_name, decoded.device_name, decoded.content, decoded.version) == (
        message.type_name,
        message.device_name,
        message.content,
        message.version,
    )
    assert decoded.metadata == message.metadata and decoded.timestamp == pytest.approx(message.timestamp, abs=1e-6)
    assert_well_formed(decoded)


def _rewrite(raw: bytes, offset: int, fmt: str, value: int) -> bytes:
    return raw[:offset] + struct.pack(fmt, value) + raw[offset + struct.calcsize(fmt) :]


MUTATIONS = {
    "truncate": lambda raw, data: raw[: data.draw(st.integers(0, len(raw) - 1))],
    "extend": lambda raw, data: raw + data.draw(st.binary(min_size=1, max_size=64)),
    "flip a byte": lambda raw, data: _flip(raw, data.draw(st.integers(0, len(raw) - 1)), data.draw(st.integers(1, 255))),
    "version": lambda raw, data: _rewrite(raw, 0, ">H", data.draw(st.integers(0, 0xFFFF))),
    "type": lambda raw, data: raw[:2] + data.draw(st.binary(min_size=12, max_size=12)) + raw[14:],
    "device": lambda raw, data: raw[:14] + data.draw(st.binary(min_size=20, max_size=20)) + raw[34:],
    "body size": lambda raw, data: _rewrite(raw, 42, ">Q", data.draw(st.integers(0, 2**64 - 1))),
    "crc": lambda raw, data: _rewrite(raw, 50, ">Q", data.draw(st.integers(0, 2**64 - 1))),
}


def _flip(raw: bytes, index: int, mask: int) -> bytes:
    return raw[:index] + bytes([raw[index] ^ mask]) + raw[index + 1 :]


@settings(max_examples=400)
@given(message=messages(), mutation=st.sampled_from(sorted(MUTATIONS)), data=st.data())
def test_a_damaged_message_is_refused_with_a_protocol_error_or_decodes_well_formed(message, mutation, data):
    raw = MUTATIONS[mutation](igtl.encode_message(message), data)
    try:
        decoded = decode(raw)
    except igtl.IgtlProtocolError:
        return
    assert_well_formed(decoded)


@settings(max_examples=300)
@given(raw=st.binary(max_size=400))
def test_any_bytes_are_refused_with_a_protocol_error_or_decode_well_formed(raw):
    try:
        decoded = decode(raw)
    except igtl.IgtlProtocolError as error:
        assert isinstance(error.status_code, int) and isinstance(error.fatal, bool)
        return
    assert_well_formed(decoded)


@settings(max_examples=200)
@given(field=st.binary(min_size=20, max_size=20))
def test_any_device_field_decodes_to_a_name_that_encodes_back(field):
    header = igtl.parse_header(igtl.HEADER.pack(1, b"TRANSFORM", field, 0, 0, igtl.crc64(b"")))
    assert igtl.encode_device_name(header.device_name) == field.split(b"\0", 1)[0]


@settings(max_examples=300)
@given(content=transform_contents, device=st.sampled_from(KNOWN_TRACKER_DEVICES))
def test_a_transform_of_any_floats_is_a_pose_or_refused_with_an_input_error(content, device):
    pose = igtl.unpack_transform(content)
    assert pose.shape == (4, 4)
    tracker = TrackerState()
    try:
        tracker.update_pose(device, pose, 0.0)
    except ThrsimInputError:
        return
    assert np.all(np.isfinite(tracker.poses[device].value)), "a NaN or infinite pose was stored"


def test_a_force_whose_magnitude_overflows_is_refused():
    # found by the listener's fuzz: a JSON reply of an infinite force was a traceback
    with pytest.raises(ThrsimInputError, match="magnitude overflows"):
        TrackerState().update_force(np.array([1e300, 1e300]), 0.0)


# --- the listener, over a real socket -----------------------------------------------------------


class _Lines(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@pytest.fixture(scope="module")
def listener():
    """One listener for every example (it must survive them all) and the lines its logger writes."""
    lines = _Lines()
    logger = logging.getLogger("thrsim.io.server")
    logger.addHandler(lines)
    server = RunningServer(IgtlServer(IgtlConfig(port=0, io_timeout_s=2.0, max_body_bytes=4096)))
    yield server, lines
    server.stop()
    logger.removeHandler(lines)


def _raw(type_name: str, device: str, content: bytes, version: int) -> bytes:
    return igtl.encode_message(igtl.Message(type_name, device, content, version=version))


def _rigid_pose_m(draw) -> np.ndarray:
    quaternion = np.array(draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1)))
    w, x, y, z = quaternion / np.linalg.norm(quaternion)
    pose = np.eye(4)
    pose[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    pose[:3, 3] = draw(st.lists(st.floats(-1e30, 1e30), min_size=3, max_size=3))  # metres; the wire has mm in float32
    return pose


@st.composite
def good_messages(draw) -> bytes:
    """A message the listener uses or ignores without complaint: a rigid pose of a known device,
    a finite force, or a type the trainer does not use under any name."""
    version = draw(st.sampled_from((1, 2)))
    kind = draw(st.sampled_from(("pose", "force", "ignored")))
    if kind == "pose":
        return _raw("TRANSFORM", draw(st.sampled_from(KNOWN_TRACKER_DEVICES)), igtl.pack_transform(_rigid_pose_m(draw)), version)
    if kind == "force":
        return _raw("SENSOR", "ForceSensor", igtl.pack_sensor(draw(st.lists(st.floats(-1e150, 1e150), min_size=1, max_size=4))), version)
    return _raw(draw(st.sampled_from(IGNORED_TYPES)), draw(device_names), draw(st.binary(max_size=100)), version)


@st.composite
def bad_messages(draw) -> bytes:
    """A message framed intact but unusable: one STATUS and one log line, then the connection goes on."""
    version = draw(st.sampled_from((1, 2)))
    device = draw(st.sampled_from(KNOWN_TRACKER_DEVICES))
    kind = draw(
        st.sampled_from(("crc", "not finite", "not rigid", "transform size", "no force", "overflow", "unit", "sensor size", "v2 short"))
    )
    if kind == "crc":
        raw = bytearray(_raw(draw(type_names), draw(device_names), draw(contents), version))
        raw[50 + draw(st.integers(0, 7))] ^= draw(st.integers(1, 255))
        return bytes(raw)
    if kind == "not finite":
        values = draw(st.lists(any_float32, min_size=12, max_size=12).filter(lambda v: not np.all(np.isfinite(v))))
        return _raw("TRANSFORM", device, struct.pack(">12f", *values), version)
    if kind == "not rigid":
        pose = np.diag([draw(st.floats(1.5, 100)), 1.0, 1.0, 1.0])
        return _raw("TRANSFORM", device, igtl.pack_transform(pose), version)
    if kind == "transform size":
        return _raw("TRANSFORM", device, draw(st.binary(max_size=100).filter(lambda b: len(b) != 48)), version)
    if kind == "no force":
        value = draw(st.sampled_from((float("nan"), float("inf"), float("-inf"))))
        return _raw(
            "SENSOR",
            "ForceSensor",
            struct.pack(">BBQ", 0, 0, igtl.UNIT_NEWTON) if draw(st.booleans()) else igtl.pack_sensor([value]),
            version,
        )
    if kind == "overflow":  # finite components, a magnitude beyond float64
        return _raw("SENSOR", "ForceSensor", igtl.pack_sensor(draw(st.lists(st.floats(1e155, 1e308), min_size=2, max_size=4))), version)
    if kind == "unit":
        return _raw(
            "SENSOR",
            "ForceSensor",
            igtl.pack_sensor([10.0], unit=draw(st.integers(1, 2**64 - 1).filter(lambda u: u != igtl.UNIT_NEWTON))),
            version,
        )
    if kind == "sensor size":
        count = draw(st.integers(1, 255))
        values = draw(st.binary(max_size=40).filter(lambda extra: len(extra) != 8 * count))
        return _raw("SENSOR", "ForceSensor", struct.pack(">BBQ", count, 0, 0) + values, version)
    body = draw(st.binary(max_size=11))  # a version-2 body shorter than its extended header
    return igtl.HEADER.pack(2, draw(type_names).encode(), b"X", 0, len(body), igtl.crc64(body)) + body


FATAL = ("garbage", "truncated header", "truncated body", "oversize", "type", "version")


@st.composite
def fatal_tails(draw, kind: str) -> bytes:
    """The end of a stream the listener cannot resynchronise after: one log line, then it closes."""
    valid = _raw("TRANSFORM", "ReamerToReference", igtl.pack_transform(np.eye(4)), 1)
    if kind == "garbage":  # a first byte above zero: header version 256 or more
        return draw(st.binary(min_size=1, max_size=600).filter(lambda b: b[0] != 0))
    if kind == "truncated header":
        return valid[: draw(st.integers(1, igtl.HEADER_SIZE - 1))]
    if kind == "truncated body":
        return valid[: draw(st.integers(igtl.HEADER_SIZE, len(valid) - 1))]
    if kind == "oversize":
        return igtl.HEADER.pack(1, b"TRANSFORM", b"X", 0, draw(st.integers(4097, 2**64 - 1)), 0) + draw(st.binary(max_size=64))
    if kind == "type":
        bad_type = draw(
            st.binary(min_size=12, max_size=12).filter(lambda t: any(b < 0x20 or b > 0x7E for b in t.split(b"\0", 1)[0]) or t[0] == 0)
        )
        return valid[:2] + bad_type + valid[14:]
    return struct.pack(">H", draw(st.integers(0, 0xFFFF).filter(lambda v: v not in igtl.SUPPORTED_VERSIONS))) + valid[2:]


@st.composite
def streams(draw, tail: str | None) -> tuple[bytes, int]:
    """Bytes a peer sends and how many bad messages they hold: up to 6 good or bad messages, then the ``tail`` kind of fatal one."""
    parts, bad = [], 0
    for _ in range(draw(st.integers(0, 6))):
        if draw(st.booleans()):
            parts.append(draw(bad_messages()))
            bad += 1
        else:
            parts.append(draw(good_messages()))
    if tail is not None:
        parts.append(draw(fatal_tails(tail)))
        bad += 1
    return b"".join(parts), bad


def _exchange(port: int, data: bytes) -> int:
    """Send ``data``, end the stream and read replies until the listener closes; returns our port."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        own_port = sock.getsockname()[1]
        with contextlib.suppress(OSError):  # the listener may close before it has read everything
            sock.sendall(data)
            sock.shutdown(socket.SHUT_WR)
        with contextlib.suppress(OSError):
            while sock.recv(65536):
                continue
    return own_port


@pytest.mark.parametrize("tail", [None, *FATAL])
@settings(max_examples=15)
@given(data=st.data())
def test_the_listener_logs_one_line_per_bad_message_and_goes_on(listener, tail, data):
    server, lines = listener
    data, bad = data.draw(streams(tail))
    lines.records.clear()
    own_port = _exchange(server.port, data)
    mine = [record.getMessage() for record in lines.records if f"from 127.0.0.1:{own_port} refused" in record.getMessage()]
    assert len(mine) == bad, mine
    assert not any(record.exc_info or "\n" in record.getMessage() for record in lines.records)
    assert server.server.stats["internal_errors"] == 0
    with server.connect() as tracker:  # the listener still serves a tracker
        tracker.sendall(transform_message(reamer_pose_mm()))
        reply = read_message(tracker)
    assert (reply.type_name, reply.device_name) == ("STRING", NAVIGATION_STATE)
