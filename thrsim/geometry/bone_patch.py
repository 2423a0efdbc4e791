"""The default acetabular bone: a spherical-shell patch around the cavity pole, meshed by gmsh.

Bone frame: origin at the centre of the acetabular sphere, +z out of the acetabulum
toward the surgeon, the patch around −z. The patch is the shell between the inner (articular)
sphere and the outer sphere, cut by a cone of the given half-angle about −z, so its side faces
are conical and meet both spheres at right angles.

Node sets: ``inner`` (the articular face that is reamed), ``outer`` (the bottom face, fixed by
the encastre [5.3.3]: the mesh's fixed nodes) and ``side`` (cuts through bone that continues in
reality; the solver holds them on an elastic foundation by default, see
:class:`thrsim.config.BonePatchConfig` and :mod:`thrsim.physics.support`). The left hip is the mirror of the right
across the bone frame's x = 0 plane, standing in for the sagittal plane.

Determinism: one gmsh thread, the Delaunay 3-D algorithm and a fixed random seed give the same
mesh for the same parameters and gmsh version.
"""

from __future__ import annotations

import math
import signal
import threading

import numpy as np

from thrsim.config import BonePatchConfig
from thrsim.geometry.mesh import INNER, OUTER, SIDE, TetMesh
from thrsim.geometry.tet_metrics import signed_volumes

_GMSH_TET = 4  # gmsh element type code of the 4-node tetrahedron
_SEED = 20406
#: node coordinates are snapped to multiples of 1/NODE_GRID_PER_MM mm (1 nm)
NODE_GRID_PER_MM = 1e6


def generate_bone_patch(config: BonePatchConfig | None = None) -> TetMesh:
    """Mesh the patch with gmsh (OpenCASCADE kernel) and return it in metres."""
    import gmsh

    config = config or BonePatchConfig()
    r_in, r_out = config.inner_radius_mm, config.inner_radius_mm + config.thickness_mm
    started_here = not gmsh.isInitialized()
    if started_here:
        _initialize_gmsh(gmsh)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add("acetabular_patch")
        occ = gmsh.model.occ
        outer = occ.addSphere(0, 0, 0, r_out)
        inner = occ.addSphere(0, 0, 0, r_in)
        length = 1.5 * r_out
        cone = occ.addCone(0, 0, 0, 0, 0, -length, 0, length * math.tan(config.half_angle))
        shell, _ = occ.cut([(3, outer)], [(3, inner)])
        patch, _ = occ.intersect(shell, [(3, cone)])
        occ.synchronize()

        faces = {OUTER: [], INNER: [], SIDE: []}
        for dim, tag in gmsh.model.getBoundary(patch, oriented=False):
            kind = gmsh.model.getType(dim, tag)
            if kind == "Sphere":
                centre = np.array(occ.getCenterOfMass(dim, tag))
                faces[OUTER if np.linalg.norm(centre) > 0.5 * (r_in + r_out) else INNER].append(tag)
            else:
                faces[SIDE].append(tag)

        gmsh.option.setNumber("Mesh.MeshSizeMax", config.element_size_mm)
        gmsh.option.setNumber("Mesh.MeshSizeMin", config.min_element_size_mm)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 1)
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        gmsh.option.setNumber("Mesh.Algorithm3D", 1)
        gmsh.option.setNumber("Mesh.RandomSeed", _SEED)
        gmsh.option.setNumber("Mesh.Optimize", 1)
        gmsh.model.mesh.generate(3)

        types, _, connectivity = gmsh.model.mesh.getElements(3)
        tet_tags = np.asarray(connectivity[list(types).index(_GMSH_TET)], dtype=np.int64).reshape(-1, 4)
        node_tags, coords, _ = gmsh.model.mesh.getNodes()
        coords = np.asarray(coords).reshape(-1, 3)
        used = np.unique(tet_tags)
        index_of = np.full(int(max(node_tags.max(), used.max())) + 1, -1, dtype=np.int64)
        index_of[used] = np.arange(len(used))
        position = np.empty((int(node_tags.max()) + 1, 3))
        position[np.asarray(node_tags, dtype=np.int64)] = coords
        # gmsh's coordinates differ in the last bits between CPUs (its libm is dispatched by CPU
        # feature); snapping to a 1 nm grid gives every machine the same mesh
        nodes_m = np.rint(position[used] * NODE_GRID_PER_MM) / (NODE_GRID_PER_MM * 1e3)
        tets = index_of[tet_tags]

        node_sets = {}
        for name, tags in faces.items():
            ids = [np.asarray(gmsh.model.mesh.getNodes(2, t, includeBoundary=True)[0], dtype=np.int64) for t in tags]
            ids = np.concatenate(ids) if ids else np.zeros(0, dtype=np.int64)
            node_sets[name] = index_of[ids[index_of[ids] >= 0]]
    finally:
        gmsh.model.remove()
        if started_here:
            gmsh.finalize()

    inverted = signed_volumes(nodes_m, tets) < 0
    tets = np.where(inverted[:, None], tets[:, [0, 2, 1, 3]], tets)
    mesh = TetMesh(nodes=nodes_m, tets=tets, node_sets=node_sets, fixed_nodes=node_sets[OUTER])
    return mesh.mirrored(axis=0) if config.side == "left" else mesh


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
