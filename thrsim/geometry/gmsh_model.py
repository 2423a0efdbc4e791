"""What every gmsh-built bone shares: a deterministic session, and the tet mesh read back in metres.

Determinism: one gmsh thread, the Delaunay 3-D algorithm and a fixed random seed give the same
mesh for the same parameters and gmsh version; node coordinates are snapped to a 1 nm grid because
gmsh's libm is dispatched by CPU feature and differs in the last bits between CPUs.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from thrsim.errors import ThrsimInputError
from thrsim.geometry.tet_metrics import signed_volumes

_GMSH_TET = 4  # gmsh element type code of the 4-node tetrahedron
#: gmsh's random seed for every bone mesh
MESH_SEED = 20406
#: node coordinates are snapped to multiples of 1/NODE_GRID_PER_MM mm (1 nm)
NODE_GRID_PER_MM = 1e6


@contextlib.contextmanager
def gmsh_session(name: str) -> Iterator[Any]:
    """A quiet, single-threaded gmsh model named ``name``; yields the gmsh module, removes the model after."""
    import gmsh

    started_here = not gmsh.isInitialized()
    if started_here:
        _initialize_gmsh(gmsh)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add(name)
        try:
            yield gmsh
        except Exception as error:
            if type(error) is not Exception:  # gmsh raises plain Exception; anything else is not gmsh's
                raise
            raise ThrsimInputError(f"gmsh cannot build the {name} with these settings: {error}") from None
    finally:
        gmsh.model.remove()
        if started_here:
            gmsh.finalize()


def set_mesh_options(gmsh, element_size_mm: float, min_element_size_mm: float) -> None:
    """The options every bone mesh is generated with (sizes in the model's millimetres)."""
    gmsh.option.setNumber("Mesh.MeshSizeMax", element_size_mm)
    gmsh.option.setNumber("Mesh.MeshSizeMin", min_element_size_mm)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.Algorithm", 6)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.option.setNumber("Mesh.RandomSeed", MESH_SEED)
    gmsh.option.setNumber("Mesh.Optimize", 1)


@dataclass(frozen=True)
class GmshTets:
    """A generated mesh read back: nodes (m, snapped), positively oriented tets, node sets, and
    each tet's source volume tag."""

    nodes_m: np.ndarray
    tets: np.ndarray
    node_sets: dict[str, np.ndarray]
    volume_tag: np.ndarray


def read_back(gmsh, faces: dict[str, list[int]]) -> GmshTets:
    """The generated tets in metres, with the nodes of each named list of surface tags as a node set."""
    tet_blocks, volume_tags = [], []
    for _, volume in gmsh.model.getEntities(3):
        types, _, connectivity = gmsh.model.mesh.getElements(3, volume)
        if _GMSH_TET in list(types):
            block = np.asarray(connectivity[list(types).index(_GMSH_TET)], dtype=np.int64).reshape(-1, 4)
            tet_blocks.append(block)
            volume_tags.append(np.full(len(block), volume, dtype=np.int64))
    tet_tags = np.concatenate(tet_blocks)
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    coords = np.asarray(coords).reshape(-1, 3)
    used = np.unique(tet_tags)
    index_of = np.full(int(max(node_tags.max(), used.max())) + 1, -1, dtype=np.int64)
    index_of[used] = np.arange(len(used))
    position = np.empty((int(node_tags.max()) + 1, 3))
    position[np.asarray(node_tags, dtype=np.int64)] = coords
    nodes_m = np.rint(position[used] * NODE_GRID_PER_MM) / (NODE_GRID_PER_MM * 1e3)
    tets = index_of[tet_tags]
    node_sets = {}
    for name, tags in faces.items():
        per_face = [np.asarray(gmsh.model.mesh.getNodes(2, t, includeBoundary=True)[0], dtype=np.int64) for t in tags]
        ids = np.concatenate(per_face) if per_face else np.zeros(0, dtype=np.int64)
        node_sets[name] = index_of[ids[index_of[ids] >= 0]]
    inverted = signed_volumes(nodes_m, tets) < 0
    tets = np.where(inverted[:, None], tets[:, [0, 2, 1, 3]], tets)
    return GmshTets(nodes_m=nodes_m, tets=tets, node_sets=node_sets, volume_tag=np.concatenate(volume_tags))


def _initialize_gmsh(gmsh) -> None:
    """Start gmsh, then give back the signal dispositions its C++ start-up resets.

    gmsh sets SIGPIPE (and others) to their C defaults behind Python's back: a later write to a
    closed socket, e.g. a tracker disconnecting from the server in the same process, would then
    kill the process instead of raising BrokenPipeError.
    """
    names = ("SIGPIPE", "SIGINT", "SIGTERM")
    saved = {name: signal.getsignal(getattr(signal, name)) for name in names if hasattr(signal, name)}
    gmsh.initialize(interruptible=False)
    if threading.current_thread() is threading.main_thread():
        for name, handler in saved.items():
            if handler is not None:
                signal.signal(getattr(signal, name), handler)
