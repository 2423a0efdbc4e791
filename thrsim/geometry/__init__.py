"""Bone patch and reamer shapes, meshing, mesh I/O, tet metrics and face adjacency."""

from thrsim.geometry.adjacency import FaceAdjacency, face_adjacency
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.reamer import ReamerGeometry, build_reamer
from thrsim.geometry.tet_metrics import centroids, minimum_altitudes, quality_report, signed_volumes

__all__ = [
    "FaceAdjacency",
    "ReamerGeometry",
    "TetMesh",
    "build_reamer",
    "centroids",
    "face_adjacency",
    "minimum_altitudes",
    "quality_report",
    "signed_volumes",
]
