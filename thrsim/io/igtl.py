"""OpenIGTLink codec, written by hand.

pyigtl (the PyPI package, 0.3.4) does not verify the CRC-64, drops message types it does not
know (STATUS, SENSOR, ...), blocks without a peer, serves one client at a time and installs
signal handlers; a trainer that must stay up through malformed input needs every byte checked
and nothing blocking, so the framing lives here (:mod:`thrsim.io.server` uses it; pyigtl stays a
test peer). Wire format, big-endian: a 58-byte header (u16 version, char[12] type, char[20]
device, u64 timestamp = seconds << 32 | fraction, u64 body size, u64 CRC-64 ECMA-182 of the
body), then the body; version 2 bodies wrap the content in an extended header and metadata
(:func:`decode_body`). TRANSFORM translations are in millimetres, as in 3D Slicer and PLUS.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass, field

import numpy as np

HEADER = struct.Struct(">H12s20sQQQ")
HEADER_SIZE = HEADER.size  # 58
EXTENDED_HEADER = struct.Struct(">HHII")
SUPPORTED_VERSIONS = (1, 2)

CRC64_POLYNOMIAL = 0x42F0E1EBA9EA3693  # ECMA-182, MSB first, initial value 0, no final XOR
_MASK64 = (1 << 64) - 1

ENCODING_ASCII = 3
ENCODING_UTF8 = 106

# STATUS codes used in replies (OpenIGTLink STATUS message).
STATUS_OK = 1
STATUS_UNKNOWN_ERROR = 2
STATUS_BUSY = 6
STATUS_TIMEOUT = 7
STATUS_OVERFLOW = 8
STATUS_CHECKSUM_ERROR = 9
STATUS_CONFIGURATION_ERROR = 10
STATUS_ILLEGAL_INSTRUCTION = 12

# SENSOR unit field: prefix << 60, then per slot i: unit << (10(5−i) + 4), exponent << 10(5−i).
UNIT_NEWTON = (0x0B << 54) | (1 << 50)
UNIT_NEWTON_METRE = UNIT_NEWTON | (0x01 << 44) | (1 << 40)  # newton^1 · metre^1 (0x01 is the metre)


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 56
        for _ in range(8):
            crc = ((crc << 1) ^ CRC64_POLYNOMIAL) if crc & (1 << 63) else (crc << 1)
        table.append(crc & _MASK64)
    return table


_CRC_TABLE = _crc_table()


def crc64(data: bytes, crc: int = 0) -> int:
    """CRC-64 ECMA-182 as OpenIGTLink computes it (table-driven, one byte per step)."""
    table = _CRC_TABLE
    for byte in data:
        crc = table[((crc >> 56) ^ byte) & 0xFF] ^ ((crc << 8) & _MASK64)
    return crc


class IgtlProtocolError(ValueError):
    """A message that cannot be used. ``fatal``: the stream's framing can no longer be trusted."""

    def __init__(self, message: str, status_code: int = STATUS_UNKNOWN_ERROR, fatal: bool = False):
        super().__init__(message)
        self.status_code = status_code
        self.fatal = fatal


@dataclass(frozen=True)
class Header:
    version: int
    type_name: str
    device_name: str
    timestamp: float
    body_size: int
    crc: int


@dataclass
class Message:
    type_name: str
    device_name: str
    content: bytes
    timestamp: float = field(default_factory=time.time)
    version: int = 1
    metadata: dict[str, str] = field(default_factory=dict)
    message_id: int = 0


def _timestamp_to_wire(seconds: float) -> int:
    whole = int(seconds)
    fraction = min(int((seconds - whole) * 2**32), 2**32 - 1)
    return (whole << 32) | fraction


def _text_field(raw: bytes, what: str) -> str:
    text = raw.split(b"\0", 1)[0]
    if any(b < 0x20 or b > 0x7E for b in text):
        raise IgtlProtocolError(f"{what} field is not printable ASCII", fatal=True)
    return text.decode("ascii")


def parse_header(raw: bytes) -> Header:
    """Decode a 58-byte header; a bad version or non-ASCII type means a desynchronised stream."""
    if len(raw) != HEADER_SIZE:
        raise IgtlProtocolError(f"header is {len(raw)} bytes, expected {HEADER_SIZE}", fatal=True)
    version, type_raw, device_raw, stamp, body_size, crc = HEADER.unpack(raw)
    if version not in SUPPORTED_VERSIONS:
        raise IgtlProtocolError(f"unsupported header version {version}", STATUS_CONFIGURATION_ERROR, fatal=True)
    type_name = _text_field(type_raw, "type")
    if not type_name:
        raise IgtlProtocolError("empty message type", fatal=True)
    # Device names are free text in practice; undecodable bytes must not cost the connection.
    # latin-1 maps every byte to one character and back (encode_device_name): symmetric.
    device_name = device_raw.split(b"\0", 1)[0].decode("latin-1")
    return Header(version, type_name, device_name, (stamp >> 32) + (stamp & 0xFFFFFFFF) / 2**32, body_size, crc)


def decode_body(header: Header, body: bytes, crc: int | None = None) -> Message:
    """Check the CRC (``crc`` may be precomputed off the event loop) and split a v2 body: a 12-byte
    extended header (u16 its size, u16 metadata header size, u32 metadata body size, u32 message
    id), the content, the metadata header (u16 count, then count × (u16 key size, u16 encoding,
    u32 value size)) and the metadata body (keys and values)."""
    if len(body) != header.body_size:
        raise IgtlProtocolError(f"body is {len(body)} bytes, header says {header.body_size}", fatal=True)
    actual = crc64(body) if crc is None else crc
    if actual != header.crc:
        raise IgtlProtocolError(f"CRC-64 mismatch for {header.type_name} {header.device_name!r}", STATUS_CHECKSUM_ERROR)
    if header.version == 1:
        return Message(header.type_name, header.device_name, body, header.timestamp, 1)
    if len(body) < EXTENDED_HEADER.size:
        raise IgtlProtocolError("version-2 body shorter than its extended header")
    extended_size, meta_header_size, meta_body_size, message_id = EXTENDED_HEADER.unpack_from(body)
    content_end = len(body) - meta_header_size - meta_body_size
    if extended_size < EXTENDED_HEADER.size or content_end < extended_size:
        raise IgtlProtocolError("version-2 extended header sizes do not fit the body")
    metadata = _decode_metadata(body[content_end : content_end + meta_header_size], body[content_end + meta_header_size :])
    return Message(header.type_name, header.device_name, body[extended_size:content_end], header.timestamp, 2, metadata, message_id)


def _decode_metadata(index: bytes, values: bytes) -> dict[str, str]:
    if not index:
        return {}
    if len(index) < 2:
        raise IgtlProtocolError("metadata header too short")
    (count,) = struct.unpack_from(">H", index)
    if len(index) != 2 + 8 * count:
        raise IgtlProtocolError(f"metadata header is {len(index)} bytes for {count} entries")
    metadata, offset = {}, 0
    for k in range(count):
        key_size, encoding, value_size = struct.unpack_from(">HHI", index, 2 + 8 * k)
        if offset + key_size + value_size > len(values):
            raise IgtlProtocolError("metadata entry runs past the body")
        key = values[offset : offset + key_size].decode("utf-8", errors="replace")
        offset += key_size
        metadata[key] = values[offset : offset + value_size].decode("ascii" if encoding == ENCODING_ASCII else "utf-8", errors="replace")
        offset += value_size
    return metadata


def encode_device_name(name: str) -> bytes:
    """The header's device field, the inverse of :func:`parse_header`'s decoding: latin-1, one
    byte per character, so every name read from a peer (any bytes up to 20) goes back unchanged."""
    try:
        raw = name.encode("latin-1")
    except UnicodeEncodeError:
        raise ValueError(f"device name {name!r} has characters outside latin-1") from None
    if len(raw) > 20:
        raise ValueError(f"device name {name!r} is {len(raw)} bytes, more than 20")
    return raw


def encode_message(message: Message) -> bytes:
    """Header + body; version-2 messages carry the extended header and the metadata."""
    if message.version == 2:
        index, values = b"", b""
        if message.metadata:
            index = struct.pack(">H", len(message.metadata))
            for key, value in message.metadata.items():
                key_bytes, value_bytes = key.encode("utf-8"), value.encode("utf-8")
                index += struct.pack(">HHI", len(key_bytes), ENCODING_UTF8, len(value_bytes))
                values += key_bytes + value_bytes
        body = EXTENDED_HEADER.pack(EXTENDED_HEADER.size, len(index), len(values), message.message_id) + message.content + index + values
    elif message.version == 1:
        body = message.content
    else:
        raise ValueError(f"cannot encode header version {message.version}")
    device = encode_device_name(message.device_name)
    if len(message.type_name) > 12:
        raise ValueError(f"type {message.type_name!r} too long (12 bytes)")
    header = HEADER.pack(
        message.version,
        message.type_name.encode("ascii"),
        device,
        _timestamp_to_wire(message.timestamp),
        len(body),
        crc64(body),
    )
    return header + body


# --- content of the message types the trainer uses ---------------------------------------

_TRANSFORM = struct.Struct(">12f")


def pack_transform(pose_m: np.ndarray) -> bytes:
    """4×4 pose (translation in metres) → TRANSFORM content (rotation column-major, then mm)."""
    pose_m = np.asarray(pose_m, dtype=float)
    return _TRANSFORM.pack(*pose_m[:3, :3].T.ravel(), *(pose_m[:3, 3] * 1e3))


def unpack_transform(content: bytes) -> np.ndarray:
    """TRANSFORM content → 4×4 pose with translation in metres (not yet checked for rigidity)."""
    if len(content) != _TRANSFORM.size:
        raise IgtlProtocolError(f"TRANSFORM content is {len(content)} bytes, expected 48", STATUS_CONFIGURATION_ERROR)
    values = _TRANSFORM.unpack(content)
    pose = np.eye(4)
    pose[:3, :3] = np.array(values[:9]).reshape(3, 3).T
    pose[:3, 3] = np.array(values[9:]) * 1e-3
    return pose


def pack_string(text: str) -> bytes:
    encoded = text.encode("utf-8")
    if len(encoded) > 0xFFFF:
        raise ValueError(f"STRING content of {len(encoded)} bytes exceeds 65535")
    encoding = ENCODING_ASCII if encoded.isascii() else ENCODING_UTF8
    return struct.pack(">HH", encoding, len(encoded)) + encoded


def unpack_string(content: bytes) -> str:
    if len(content) < 4:
        raise IgtlProtocolError("STRING content shorter than 4 bytes")
    encoding, length = struct.unpack_from(">HH", content)
    if len(content) < 4 + length:
        raise IgtlProtocolError(f"STRING declares {length} bytes, has {len(content) - 4}")
    return content[4 : 4 + length].decode("ascii" if encoding == ENCODING_ASCII else "utf-8", errors="replace")


def pack_sensor(values: list[float] | np.ndarray, unit: int = UNIT_NEWTON) -> bytes:
    """SENSOR content: u8 count, u8 status (0), u64 unit (one unit for every value), count × f64."""
    values = [float(v) for v in values]
    if not 0 < len(values) <= 255:
        raise ValueError("SENSOR carries 1 to 255 values")
    return struct.pack(f">BBQ{len(values)}d", len(values), 0, unit, *values)


def unpack_sensor(content: bytes) -> tuple[np.ndarray, int]:
    """SENSOR content → (values, unit field)."""
    if len(content) < 10:
        raise IgtlProtocolError("SENSOR content shorter than 10 bytes")
    count, _status, unit = struct.unpack_from(">BBQ", content)
    if len(content) != 10 + 8 * count:
        raise IgtlProtocolError(f"SENSOR declares {count} values in {len(content)} bytes")
    return np.array(struct.unpack_from(f">{count}d", content, 10)), unit


def pack_status(code: int, error_name: str = "", text: str = "", subcode: int = 0) -> bytes:
    return struct.pack(">Hq20s", code, subcode, error_name.encode("ascii", errors="replace")[:20]) + text.encode("utf-8") + b"\0"


def unpack_status(content: bytes) -> tuple[int, str, str]:
    """STATUS content → (code, error name, message)."""
    if len(content) < 30:
        raise IgtlProtocolError("STATUS content shorter than 30 bytes")
    code, _subcode, name = struct.unpack_from(">Hq20s", content)
    return (
        code,
        name.split(b"\0", 1)[0].decode("ascii", errors="replace"),
        content[30:].split(b"\0", 1)[0].decode("utf-8", errors="replace"),
    )
