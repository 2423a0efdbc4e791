"""The hand-written OpenIGTLink codec: CRC-64 ECMA-182, header versions 1 and 2, message
contents, byte-exact interoperability with pyigtl, and refusal of malformed input."""

from __future__ import annotations

import contextlib
import os
import struct

import crcmod
import numpy as np
import pyigtl
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thrsim.io import igtl

pytestmark = pytest.mark.timeout(30)

PYIGTL_CRC = crcmod.mkCrcFun(0x142F0E1EBA9EA3693, rev=False, initCrc=0, xorOut=0)  # pyigtl's own


def test_crc64_check_value_and_agreement_with_crcmod():
    assert igtl.crc64(b"123456789") == 0x6C40DF5F0B497347  # CRC-64/ECMA-182 check value
    for size in (0, 1, 48, 4096):
        data = os.urandom(size)
        assert igtl.crc64(data) == PYIGTL_CRC(data)


def pose_m() -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    pose[:3, 3] = [0.012, -0.034, 0.5]
    return pose


@pytest.mark.parametrize("version", [1, 2])
def test_pyigtl_transform_decodes_here(version):
    matrix_mm = pose_m()
    matrix_mm[:3, 3] *= 1e3
    message = pyigtl.TransformMessage(matrix_mm, device_name="ReamerToReference")
    message.header_version = version
    if version == 2:
        message.metadata = {"Status": "OK", "Tool": "reamer 45"}
    raw = message.pack()
    header = igtl.parse_header(raw[: igtl.HEADER_SIZE])
    decoded = igtl.decode_body(header, raw[igtl.HEADER_SIZE :])
    assert (decoded.type_name, decoded.device_name, decoded.version) == ("TRANSFORM", "ReamerToReference", version)
    assert igtl.unpack_transform(decoded.content) == pytest.approx(pose_m(), abs=1e-6)
    assert decoded.metadata == ({"Status": "OK", "Tool": "reamer 45"} if version == 2 else {})
    assert header.timestamp == pytest.approx(message.timestamp, abs=1e-6)


@pytest.mark.parametrize("version", [1, 2])
def test_messages_encoded_here_decode_in_pyigtl(version):
    raw = igtl.encode_message(
        igtl.Message(
            "STRING", "NavigationState", igtl.pack_string('{"a": 1}'), version=version, metadata={"k": "v"} if version == 2 else {}
        )
    )
    fields = pyigtl.MessageBase.parse_header(raw[:58])
    message = pyigtl.MessageBase.create_message(fields["message_type"])
    message.unpack(fields, raw[58:])
    assert message.string == '{"a": 1}' and message.device_name == "NavigationState"
    assert PYIGTL_CRC(raw[58:]) == struct.unpack(">Q", raw[50:58])[0]
    if version == 2:
        assert message.metadata == {"k": "v"}
    transform = igtl.encode_message(igtl.Message("TRANSFORM", "SimReamerToReference", igtl.pack_transform(pose_m()), version=version))
    fields = pyigtl.MessageBase.parse_header(transform[:58])
    message = pyigtl.MessageBase.create_message("TRANSFORM")
    message.unpack(fields, transform[58:])
    expected = pose_m()
    expected[:3, 3] *= 1e3
    assert message.matrix == pytest.approx(expected, abs=1e-4)


def test_sensor_and_status_round_trip():
    values, unit = igtl.unpack_sensor(igtl.pack_sensor([1.5, -2.0, 230.0]))
    assert values.tolist() == [1.5, -2.0, 230.0] and unit == igtl.UNIT_NEWTON
    assert igtl.UNIT_NEWTON == 0x02C4000000000000  # newton^1 in unit slot 0, per igtl_unit_pack
    code, name, text = igtl.unpack_status(igtl.pack_status(igtl.STATUS_CHECKSUM_ERROR, "BadMessage", "CRC-64 mismatch"))
    assert (code, name, text) == (9, "BadMessage", "CRC-64 mismatch")
    assert igtl.unpack_string(igtl.pack_string("ünïcode")) == "ünïcode"


def valid_raw(version: int = 1) -> bytes:
    return igtl.encode_message(igtl.Message("TRANSFORM", "ReamerToReference", igtl.pack_transform(pose_m()), version=version))


def test_bad_crc_is_a_recoverable_checksum_error():
    raw = bytearray(valid_raw())
    raw[-1] ^= 0xFF
    header = igtl.parse_header(bytes(raw[:58]))
    with pytest.raises(igtl.IgtlProtocolError) as info:
        igtl.decode_body(header, bytes(raw[58:]))
    assert info.value.status_code == igtl.STATUS_CHECKSUM_ERROR and not info.value.fatal


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda raw: raw[:30], "header is 30 bytes"),
        (lambda raw: struct.pack(">H", 7) + raw[2:58], "unsupported header version 7"),
        (lambda raw: raw[:2] + b"TRANS\xffFORM\0\0" + raw[14:58], "not printable ASCII"),
        (lambda raw: raw[:2] + b"\0" * 12 + raw[14:58], "empty message type"),
    ],
)
def test_fatal_header_errors(mutate, message):
    with pytest.raises(igtl.IgtlProtocolError, match=message) as info:
        igtl.parse_header(mutate(valid_raw()))
    assert info.value.fatal


def test_version_2_extended_header_that_does_not_fit_is_refused():
    content = igtl.pack_transform(pose_m())
    body = igtl.EXTENDED_HEADER.pack(12, 0, 500, 0) + content  # metadata larger than the body
    header = igtl.Header(2, "TRANSFORM", "X", 0.0, len(body), igtl.crc64(body))
    with pytest.raises(igtl.IgtlProtocolError, match="do not fit"):
        igtl.decode_body(header, body)


@pytest.mark.parametrize(
    "unpack, content",
    [
        (igtl.unpack_transform, b"\0" * 47),
        (igtl.unpack_sensor, b"\x03\x00" + b"\0" * 8 + b"\0" * 16),
        (igtl.unpack_string, b"\x00\x03\x00\x10abc"),
        (igtl.unpack_status, b"\0" * 10),
    ],
)
def test_short_or_inconsistent_contents_are_refused(unpack, content):
    with pytest.raises(igtl.IgtlProtocolError):
        unpack(content)


@settings(max_examples=300, deadline=None)
@given(data=st.binary(min_size=58, max_size=200))
def test_random_bytes_never_raise_anything_but_protocol_errors(data):
    # any other exception type escapes the suppress blocks and fails the test
    with contextlib.suppress(igtl.IgtlProtocolError):
        header = igtl.parse_header(data[:58])
        message = igtl.decode_body(header, data[58 : 58 + header.body_size])
        for unpack in (igtl.unpack_transform, igtl.unpack_sensor, igtl.unpack_string, igtl.unpack_status):
            with contextlib.suppress(igtl.IgtlProtocolError):
                unpack(message.content)


def test_device_names_round_trip_as_latin_1_within_20_bytes():
    for name in ("ReamerToReference", "\u00e9" * 20, "T\u00f6\u00f6l"):
        raw = igtl.encode_message(igtl.Message("TRANSFORM", name, igtl.pack_transform(np.eye(4))))
        header = igtl.parse_header(raw[: igtl.HEADER_SIZE])
        assert header.device_name == name
        assert raw[14 : 14 + len(name)] == name.encode("latin-1")
    for bad in ("x" * 21, "\u20ac", "\u00e9" * 21):
        with pytest.raises(ValueError):
            igtl.encode_message(igtl.Message("TRANSFORM", bad, b""))
    # any 20 bytes a peer sends decode to a name that encodes back to the same bytes
    every_byte = bytes(range(1, 256))
    for start in range(0, len(every_byte), 20):
        chunk = every_byte[start : start + 20]
        header = igtl.HEADER.pack(1, b"STATUS", chunk, 0, 0, igtl.crc64(b""))
        assert igtl.encode_device_name(igtl.parse_header(header).device_name) == chunk


def test_sensor_messages_encoded_here_are_pyigtls_byte_for_byte_and_decode_there():
    """The trainer's force SENSORs (ReamerReaction in N, ReamerTorque in N·m) read by pyigtl's parser,
    with a SENSOR class written from the specification (pyigtl has none)."""
    from pyigtl_sensor import SensorMessage, register

    register()
    for device, value, unit in (("ReamerReaction", 231.25, igtl.UNIT_NEWTON), ("ReamerTorque", 1.5, igtl.UNIT_NEWTON_METRE)):
        raw = igtl.encode_message(igtl.Message("SENSOR", device, igtl.pack_sensor([value], unit), timestamp=1234.0))
        assert raw == SensorMessage([value], unit, timestamp=1234.0, device_name=device).pack()
        fields = pyigtl.MessageBase.parse_header(raw[:58])
        message = pyigtl.MessageBase.create_message(fields["message_type"])
        message.unpack(fields, raw[58:])
        assert (message.device_name, message.values, message.unit) == (device, [value], unit)
    # the unit fields as the specification lays them out: prefix (4 bits) none, then unit (6) and exponent (4) slots
    assert f"{igtl.UNIT_NEWTON:064b}"[:24] == "0000" + "001011" + "0001" + "000000" + "0000"  # newton^1
    assert f"{igtl.UNIT_NEWTON_METRE:064b}"[:24] == "0000" + "001011" + "0001" + "000001" + "0001"  # newton^1 metre^1
