"""Elastic foundation on the bone patch's side faces (pure NumPy, no I/O).

The patch's side faces are cuts through cortical bone that continues in reality. Left free, a
tilted reamer attacks a free rim edge side-on and exaggerates the orientation effect; fixed
rigidly, the tets whose four nodes all lie on supported faces (301 in the default mesh) could
never strain, so they form an uncuttable ring that the reamer ends up resting on. Instead each
side-face node is tied to its rest position by a spring standing for the missing bone: a layer
one element size deep, fixed at its far side, over the node's tributary face area,

    k_i = E · A_i / h,

so the support is as stiff as the bone it replaces and a supported node can still be cut free.
"""

from __future__ import annotations

import numpy as np

from thrsim.geometry.mesh import TetMesh


def tributary_areas(mesh: TetMesh, node_set: np.ndarray) -> np.ndarray:
    """Per-node share (a third of each face) of the boundary faces lying wholly in ``node_set``, (N,) m²."""
    in_set = np.zeros(mesh.n_nodes, dtype=bool)
    in_set[node_set] = True
    faces = mesh.adjacency.boundary_faces
    faces = faces[in_set[faces].all(axis=1)]
    p = mesh.nodes[faces]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    share = np.zeros(mesh.n_nodes)
    np.add.at(share, faces.ravel(), np.repeat(area / 3.0, 3))
    return share


def foundation_stiffness(mesh: TetMesh, node_set: np.ndarray, youngs_modulus_pa: float, depth_m: float) -> np.ndarray:
    """Spring stiffness per node (N,) N/m: E·A_i/h on ``node_set``, zero elsewhere and on fixed nodes."""
    stiffness = youngs_modulus_pa * tributary_areas(mesh, node_set) / depth_m
    stiffness[mesh.fixed_nodes] = 0.0
    return stiffness
