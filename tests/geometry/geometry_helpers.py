"""Hand-built tet meshes and helpers for the geometry tests (imported by conftest and tests)."""

from __future__ import annotations

import numpy as np

from thrsim.geometry.tet_metrics import signed_volumes

#: coarse element size (mm) for the gmsh tests: ~1,900 tets, meshed in well under a second
COARSE_MM = 1.1

# unit cube corners, node i = x + 2y + 4z
CUBE_NODES = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=float)
# five-tet split: a central tet and four corner tets, each corner sharing one face with the centre
CUBE_TETS = np.array([[1, 2, 4, 7], [0, 1, 2, 4], [3, 1, 2, 7], [5, 1, 4, 7], [6, 2, 4, 7]])


def orient(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Swap two nodes of every negatively oriented tet."""
    tets = np.array(tets)
    negative = signed_volumes(nodes, tets) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    return tets
