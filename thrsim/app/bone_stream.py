"""Binary WebSocket frames of the bone being reamed, and the mesh the page draws them on.

The state of every element is one byte (:meth:`thrsim.app.reaming.ReamingTrainer.display_levels`:
0 removed, 1..32 α). Each viewer is sent only what changed since what *it* last received, so a
slow viewer that skipped states still ends up exact. Little-endian layouts:

* keyframe ``b"K"``, u32 frame, u32 n, n × u8 levels (on connect, or when most elements changed);
* delta ``b"D"``, u32 frame, u32 m, m × u16 element ids (u32 when the mesh has ≥ 65,536
  elements), m × u8 levels.

The mesh (``GET /api/reaming/mesh``): ``b"THRM"``, u32 version, u32 nodes, u32 elements, then
nodes (N×3 f32, mm, the patch frame), tets (E×4 u32) and face neighbours (E×4 i32, −1 on the
boundary, local face i opposite vertex i).
"""

from __future__ import annotations

import struct

import numpy as np

from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import TetMesh

MESH_MAGIC = b"THRM"
MESH_VERSION = 1
_HEADER = struct.Struct("<cII")
#: above this fraction of changed elements a keyframe is smaller than a delta
_KEYFRAME_FRACTION = 0.3


def mesh_payload(mesh: TetMesh) -> bytes:
    """The bytes of ``GET /api/reaming/mesh``."""
    nodes = np.ascontiguousarray(mesh.nodes * 1e3, dtype="<f4")
    tets = np.ascontiguousarray(mesh.tets, dtype="<u4")
    neighbours = np.ascontiguousarray(mesh.adjacency.neighbours, dtype="<i4")
    header = MESH_MAGIC + struct.pack("<III", MESH_VERSION, mesh.n_nodes, mesh.n_tets)
    return header + nodes.tobytes() + tets.tobytes() + neighbours.tobytes()


def keyframe(frame: int, levels: np.ndarray) -> bytes:
    return _HEADER.pack(b"K", frame, len(levels)) + np.ascontiguousarray(levels, dtype=np.uint8).tobytes()


def delta(frame: int, ids: np.ndarray, levels: np.ndarray, n_elements: int) -> bytes:
    id_type = "<u2" if n_elements < 65536 else "<u4"
    return _HEADER.pack(b"D", frame, len(ids)) + np.asarray(ids, dtype=id_type).tobytes() + np.asarray(levels, dtype=np.uint8).tobytes()


def update(frame: int, sent: np.ndarray | None, current: np.ndarray) -> bytes | None:
    """What a viewer that last received ``sent`` needs to hold ``current``; None when nothing changed."""
    if sent is None or sent.shape != current.shape:
        return keyframe(frame, current)
    changed = np.flatnonzero(sent != current)
    if len(changed) == 0:
        return None
    if len(changed) > _KEYFRAME_FRACTION * len(current):
        return keyframe(frame, current)
    return delta(frame, changed, current[changed], len(current))


def apply(message: bytes, levels: np.ndarray | None) -> tuple[int, np.ndarray]:
    """Decode a frame onto ``levels`` (what the page does); returns (frame, new levels)."""
    if len(message) < _HEADER.size:
        raise ThrsimInputError("bone frame shorter than its header")
    kind, frame, count = _HEADER.unpack_from(message)
    body = message[_HEADER.size :]
    if kind == b"K":
        if len(body) != count:
            raise ThrsimInputError(f"keyframe of {count} elements carries {len(body)} bytes")
        return frame, np.frombuffer(body, dtype=np.uint8).copy()
    if kind != b"D" or levels is None:
        raise ThrsimInputError(f"unexpected bone frame {kind!r}" + (" before a keyframe" if levels is None else ""))
    id_type = np.dtype("<u2") if len(levels) < 65536 else np.dtype("<u4")
    if len(body) != count * (id_type.itemsize + 1):
        raise ThrsimInputError(f"delta of {count} elements carries {len(body)} bytes")
    ids = np.frombuffer(body[: count * id_type.itemsize], dtype=id_type)
    out = levels.copy()
    out[ids] = np.frombuffer(body[count * id_type.itemsize :], dtype=np.uint8)
    return frame, out
