"""ParaView-readable time series of a learned rollout: one .vtu per frame for the bone and for the reamer, a .pvd index.

The bone carries per-element ``alpha`` and ``removed`` (cell data, the same tets every frame, so
ParaView's Threshold on ``removed`` shows the reamed bone); the reamer is its own dataset, the
dome its teeth sweep (a triangulated hemisphere in front of the head centre), in millimetres
like the bone.
"""

from __future__ import annotations

import math
from pathlib import Path
from xml.sax.saxutils import quoteattr

import meshio
import numpy as np

from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.reamer import frame_rotation


def dome(radius_m: float, rings: int = 12, segments: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Points and triangles of a hemisphere z ≥ 0 in the reamer frame (pole at +z)."""
    points = [[0.0, 0.0, radius_m]]
    for i in range(1, rings + 1):
        polar = 0.5 * math.pi * i / rings
        for j in range(segments):
            azimuth = 2 * math.pi * j / segments
            points.append(
                [radius_m * math.sin(polar) * math.cos(azimuth), radius_m * math.sin(polar) * math.sin(azimuth), radius_m * math.cos(polar)]
            )
    triangles = [[0, 1 + j, 1 + (j + 1) % segments] for j in range(segments)]
    for i in range(rings - 1):
        a, b = 1 + i * segments, 1 + (i + 1) * segments
        for j in range(segments):
            k = (j + 1) % segments
            triangles += [[a + j, b + j, b + k], [a + j, b + k, a + k]]
    return np.array(points), np.array(triangles, dtype=np.int64)


def write_frame(
    folder: Path,
    frame: int,
    mesh: TetMesh,
    alpha: np.ndarray,
    removed: np.ndarray,
    centre_m: np.ndarray,
    axis: np.ndarray,
    teeth_radius_m: float,
) -> tuple[str, str]:
    bone_name, reamer_name = f"bone_{frame:04d}.vtu", f"reamer_{frame:04d}.vtu"
    bone = meshio.Mesh(
        mesh.nodes * 1e3,
        [("tetra", mesh.tets)],
        cell_data={"alpha": [np.asarray(alpha, dtype=np.float32)], "removed": [np.asarray(removed, dtype=np.uint8)]},
    )
    meshio.write(folder / bone_name, bone, file_format="vtu")
    points, triangles = dome(teeth_radius_m)
    placed = (points @ frame_rotation(axis).T + centre_m) * 1e3
    meshio.write(folder / reamer_name, meshio.Mesh(placed, [("triangle", triangles)]), file_format="vtu")
    return bone_name, reamer_name


def write_pvd(path: Path, entries: list[tuple[float, str, str]]) -> None:
    """``entries``: (time s, bone file, reamer file); part 0 is the bone, part 1 the reamer."""
    lines = ['<?xml version="1.0"?>', '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">', "  <Collection>"]
    for time_s, bone, reamer in entries:
        lines.append(f'    <DataSet timestep="{time_s:.9g}" group="" part="0" name="bone" file={quoteattr(bone)}/>')
        lines.append(f'    <DataSet timestep="{time_s:.9g}" group="" part="1" name="reamer" file={quoteattr(reamer)}/>')
    lines += ["  </Collection>", "</VTKFile>", ""]
    path.write_text("\n".join(lines))
