"""Small hand-built tet meshes shared by the geometry tests."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_helpers import COARSE_MM, CUBE_NODES, CUBE_TETS, orient

from thrsim.config import BonePatchConfig
from thrsim.geometry.bone_patch import generate_bone_patch


@pytest.fixture
def two_tets() -> tuple[np.ndarray, np.ndarray]:
    """Two positive tets sharing face (1, 2, 3): local face 0 of tet 0, local face 3 of tet 1."""
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    return nodes, tets


@pytest.fixture
def cube() -> tuple[np.ndarray, np.ndarray]:
    return CUBE_NODES.copy(), orient(CUBE_NODES, CUBE_TETS)


@pytest.fixture(scope="session")
def coarse_patch():
    return generate_bone_patch(BonePatchConfig(element_size_mm=COARSE_MM))
