"""Per-element measures of linear tetrahedra, vectorised over the whole mesh (no I/O).

Orientation convention: a tet (a, b, c, d) is positive when (b−a)×(c−a)·(d−a) > 0, as in
ABAQUS C3D4 and Gmsh.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

# Local faces of a tet, each listed so that its normal (right-hand rule) points outward
# for a positively oriented tet; face i is opposite vertex i.
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)

#: normalised volume quality q = 6√2·V / L_rms³ (1 for a regular tet) below which a tet is a sliver
SLIVER_QUALITY = 0.05
#: |V| below this fraction of L_rms³ counts as degenerate (zero volume)
DEGENERATE_FRACTION = 1e-9


def signed_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volume of every tet; negative means inverted."""
    a, b, c, d = (nodes[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def centroids(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Mean of each tet's four nodes, (E, 3)."""
    return nodes[tets].mean(axis=1)


def face_areas(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Area of each tet's four faces, (E, 4), face i opposite vertex i."""
    p = nodes[tets[:, TET_FACES]]  # (E, 4, 3 vertices, 3)
    return 0.5 * np.linalg.norm(np.cross(p[:, :, 1] - p[:, :, 0], p[:, :, 2] - p[:, :, 0]), axis=-1)


def minimum_altitudes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Smallest vertex-to-opposite-face distance 3V / max face area: the stable-time-step length."""
    volume = np.abs(signed_volumes(nodes, tets))
    return 3.0 * volume / face_areas(nodes, tets).max(axis=1)


def rms_edge_lengths(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    p = nodes[tets[:, TET_EDGES]]
    return np.sqrt((np.sum((p[:, :, 1] - p[:, :, 0]) ** 2, axis=-1)).mean(axis=1))


def volume_quality(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """q = 6√2·V / L_rms³: 1 for a regular tet, → 0 for slivers, negative when inverted."""
    return 6.0 * np.sqrt(2.0) * signed_volumes(nodes, tets) / rms_edge_lengths(nodes, tets) ** 3


@dataclass(frozen=True)
class QualityReport:
    elements: int
    inverted: int
    degenerate: int
    slivers: int
    min_quality: float
    median_quality: float
    min_altitude: float
    median_altitude: float

    @property
    def valid(self) -> bool:
        return self.inverted == 0 and self.degenerate == 0

    def as_dict(self) -> dict:
        return asdict(self)


def quality_report(nodes: np.ndarray, tets: np.ndarray) -> QualityReport:
    """Count inverted, degenerate (zero-volume) and sliver tets; altitude statistics."""
    volume = signed_volumes(nodes, tets)
    scale = rms_edge_lengths(nodes, tets) ** 3
    degenerate = np.abs(volume) <= DEGENERATE_FRACTION * np.maximum(scale, np.finfo(float).tiny)
    inverted = (volume < 0) & ~degenerate
    with np.errstate(divide="ignore", invalid="ignore"):
        quality = np.where(scale > 0, 6.0 * np.sqrt(2.0) * volume / scale, 0.0)
    altitude = minimum_altitudes(nodes, tets)
    slivers = (quality < SLIVER_QUALITY) & ~degenerate & ~inverted
    return QualityReport(
        elements=len(tets),
        inverted=int(inverted.sum()),
        degenerate=int(degenerate.sum()),
        slivers=int(slivers.sum()),
        min_quality=float(quality.min()) if len(tets) else float("nan"),
        median_quality=float(np.median(quality)) if len(tets) else float("nan"),
        min_altitude=float(altitude.min()) if len(tets) else float("nan"),
        median_altitude=float(np.median(altitude)) if len(tets) else float("nan"),
    )
