"""The default acetabular bone: a spherical-shell patch around the cavity pole, meshed by gmsh.

Bone frame: origin at the centre of the acetabular sphere, +z out of the acetabulum toward the
surgeon, the patch around −z: the shell between the inner (articular) and outer spheres, cut by a
cone of the given half-angle about −z, so its side faces meet both spheres at right angles.
Node sets: ``inner`` (the articular face that is reamed), ``outer`` (fixed by the encastre
[5.3.3]: the mesh's fixed nodes) and ``side`` (cuts through bone that continues; held on an
elastic foundation by default, :mod:`thrsim.physics.support`). The left hip is the mirror of the
right across x = 0, standing in for the sagittal plane. Deterministic:
:mod:`thrsim.geometry.gmsh_model`.
"""

from __future__ import annotations

import math

import numpy as np

from thrsim.config import BonePatchConfig
from thrsim.geometry.gmsh_model import gmsh_session, read_back, set_mesh_options
from thrsim.geometry.mesh import INNER, OUTER, SIDE, TetMesh


def generate_bone_patch(config: BonePatchConfig | None = None) -> TetMesh:
    """Mesh the patch with gmsh (OpenCASCADE kernel) and return it in metres."""
    config = config or BonePatchConfig()
    r_in, r_out = config.inner_radius_mm, config.inner_radius_mm + config.thickness_mm
    with gmsh_session("acetabular_patch") as gmsh:
        occ = gmsh.model.occ
        outer = occ.addSphere(0, 0, 0, r_out)
        inner = occ.addSphere(0, 0, 0, r_in)
        length = 1.5 * r_out
        cone = occ.addCone(0, 0, 0, 0, 0, -length, 0, length * math.tan(config.half_angle))
        shell, _ = occ.cut([(3, outer)], [(3, inner)])
        patch, _ = occ.intersect(shell, [(3, cone)])
        occ.synchronize()

        faces: dict[str, list[int]] = {OUTER: [], INNER: [], SIDE: []}
        for dim, tag in gmsh.model.getBoundary(patch, oriented=False):
            kind = gmsh.model.getType(dim, tag)
            if kind == "Sphere":
                centre = np.array(occ.getCenterOfMass(dim, tag))
                faces[OUTER if np.linalg.norm(centre) > 0.5 * (r_in + r_out) else INNER].append(tag)
            else:
                faces[SIDE].append(tag)

        set_mesh_options(gmsh, config.element_size_mm, config.min_element_size_mm)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 1)
        gmsh.model.mesh.generate(3)
        built = read_back(gmsh, faces)

    mesh = TetMesh(nodes=built.nodes_m, tets=built.tets, node_sets=built.node_sets, fixed_nodes=built.node_sets[OUTER])
    return mesh.mirrored(axis=0) if config.side == "left" else mesh
