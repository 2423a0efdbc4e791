"""Binary WebSocket frames of the bone being reamed, and the mesh the page draws them on.

The state of every element is one byte (:meth:`thrsim.app.reaming.ReamingTrainer.display_levels`:
0 removed, 1..32 α). Each viewer is sent only what changed since what *it* last received, so a
slow viewer that skipped states still ends up exact. A frame is a little-endian header ``kind``
(1 byte), u32 frame, u32 count, then a zlib stream (RFC 1950, what the browser's
``DecompressionStream("deflate")`` reads) of a keyframe (:func:`keyframe`) or a delta
(:func:`delta`). Changed ids go as varint gaps because gmsh numbers neighbouring tets close
together: nearly every gap takes one byte (sizes: Benchmarks and validation, page drawing
and the reaming page under load). The mesh's bytes: :func:`mesh_payload`.
"""

from __future__ import annotations

import json
import struct
import zlib

import numpy as np

from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import TetMesh

MESH_MAGIC = b"THRM"
MESH_VERSION = 2
_HEADER = struct.Struct("<cII")
#: above this fraction of changed elements a keyframe is smaller than a delta
_KEYFRAME_FRACTION = 0.3
#: zlib's fastest level: level 6 saves under 1 % more on these frames
_ZLIB_LEVEL = 1


def mesh_payload(mesh: TetMesh) -> bytes:
    """The bytes of ``GET /api/reaming/mesh``: ``b"THRM"``, u32 version, u32 nodes, u32 elements, then
    nodes (N×3 f32, mm, the patch frame), tets (E×4 u32) and face neighbours (E×4 i32, −1 on the
    boundary, local face i opposite vertex i); from version 2, each element's material (E×u8, an
    index into the names) and the material names (u32 byte length, then a UTF-8 JSON list), so the
    page draws the bone's layers."""
    nodes = np.ascontiguousarray(mesh.nodes * 1e3, dtype="<f4")
    tets = np.ascontiguousarray(mesh.tets, dtype="<u4")
    neighbours = np.ascontiguousarray(mesh.adjacency.neighbours, dtype="<i4")
    material = np.ascontiguousarray(mesh.element_material, dtype="u1")
    names = json.dumps(list(mesh.material_names)).encode()
    header = MESH_MAGIC + struct.pack("<III", MESH_VERSION, mesh.n_nodes, mesh.n_tets)
    return header + nodes.tobytes() + tets.tobytes() + neighbours.tobytes() + material.tobytes() + struct.pack("<I", len(names)) + names


def _varints(values: np.ndarray) -> bytes:
    """Non-negative integers as LEB128 varints (7 bits a byte, the high bit set on all but the last)."""
    values = np.asarray(values, dtype=np.uint64)
    width = np.ones(len(values), dtype=np.int64)
    for k in range(1, 5):
        width += values >= (1 << (7 * k))
    out = np.empty(int(width.sum()), dtype=np.uint8)
    starts = np.concatenate(([0], np.cumsum(width)[:-1]))
    for k in range(int(width.max(initial=0))):
        has = width > k
        byte = (values[has] >> np.uint64(7 * k)) & np.uint64(0x7F)
        out[starts[has] + k] = byte | np.where(width[has] > k + 1, 0x80, 0).astype(np.uint64)
    return out.tobytes()


def _read_varints(data: bytes, count: int) -> tuple[np.ndarray, int]:
    """The first ``count`` varints of ``data`` and the bytes they took."""
    raw = np.frombuffer(data, dtype=np.uint8)
    ends = np.flatnonzero(raw < 0x80)[:count]
    if len(ends) < count:
        raise ThrsimInputError(f"delta of {count} elements carries {len(ends)} ids")
    starts = np.concatenate(([0], ends[:-1] + 1))
    if np.any(ends - starts >= 5):
        raise ThrsimInputError("element id longer than 32 bits in a delta")
    values = np.zeros(count, dtype=np.int64)
    for k in range(int((ends - starts).max(initial=-1)) + 1):
        has = starts + k <= ends
        values[has] |= (raw[starts[has] + k].astype(np.int64) & 0x7F) << (7 * k)
    return values, int(ends[-1]) + 1 if count else 0


def keyframe(frame: int, levels: np.ndarray) -> bytes:
    """Frame ``b"K"``: count × u8 levels (on connect, or when most elements changed)."""
    body = np.ascontiguousarray(levels, dtype=np.uint8).tobytes()
    return _HEADER.pack(b"K", frame, len(levels)) + zlib.compress(body, _ZLIB_LEVEL)


def delta(frame: int, ids: np.ndarray, levels: np.ndarray) -> bytes:
    """Frame ``b"D"``: the count changed element ids (``ids`` ascending), each as the gap to the previous
    id minus one (the first: the id itself) in LEB128 varints, then count × u8 levels."""
    ids = np.asarray(ids, dtype=np.int64)
    gaps = np.diff(ids, prepend=-1) - 1
    body = _varints(gaps) + np.asarray(levels, dtype=np.uint8).tobytes()
    return _HEADER.pack(b"D", frame, len(ids)) + zlib.compress(body, _ZLIB_LEVEL)


def update(frame: int, sent: np.ndarray | None, current: np.ndarray) -> bytes | None:
    """What a viewer that last received ``sent`` needs to hold ``current``; None when nothing changed."""
    if sent is None or sent.shape != current.shape:
        return keyframe(frame, current)
    changed = np.flatnonzero(sent != current)
    if len(changed) == 0:
        return None
    if len(changed) > _KEYFRAME_FRACTION * len(current):
        return keyframe(frame, current)
    return delta(frame, changed, current[changed])


def apply(message: bytes, levels: np.ndarray | None) -> tuple[int, np.ndarray]:
    """Decode a frame onto ``levels`` (what the page does); returns (frame, new levels)."""
    if len(message) < _HEADER.size:
        raise ThrsimInputError("bone frame shorter than its header")
    kind, frame, count = _HEADER.unpack_from(message)
    try:
        body = zlib.decompress(message[_HEADER.size :])
    except zlib.error as error:
        raise ThrsimInputError(f"bone frame {kind!r} is not a zlib stream: {error}") from None
    if kind == b"K":
        if len(body) != count:
            raise ThrsimInputError(f"keyframe of {count} elements carries {len(body)} bytes")
        return frame, np.frombuffer(body, dtype=np.uint8).copy()
    if kind != b"D" or levels is None:
        raise ThrsimInputError(f"unexpected bone frame {kind!r}" + (" before a keyframe" if levels is None else ""))
    gaps, id_bytes = _read_varints(body, count)
    if len(body) - id_bytes != count:
        raise ThrsimInputError(f"delta of {count} elements carries {len(body) - id_bytes} levels")
    ids = np.cumsum(gaps + 1) - 1
    if count and ids[-1] >= len(levels):
        raise ThrsimInputError(f"delta names element {ids[-1]} of a mesh of {len(levels)}")
    out = levels.copy()
    out[ids] = np.frombuffer(body[id_bytes:], dtype=np.uint8)
    return frame, out
