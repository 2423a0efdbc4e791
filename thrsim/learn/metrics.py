"""Scores of removed-element predictions [7.3.5, eqs. 51–53], reamed-surface distances, the cavity's fitted
sphere and the plate left ahead of the teeth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass
class Counts:
    """True/false positives and false negatives summed over windows (micro-averaging)."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    windows: int = 0

    def add(self, predicted: np.ndarray, truth: np.ndarray) -> None:
        predicted, truth = np.asarray(predicted, bool), np.asarray(truth, bool)
        self.tp += int((predicted & truth).sum())
        self.fp += int((predicted & ~truth).sum())
        self.fn += int((~predicted & truth).sum())
        self.windows += 1

    @property
    def precision(self) -> float | None:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else None

    @property
    def recall(self) -> float | None:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else None

    @property
    def f1(self) -> float | None:
        if self.tp + self.fp + self.fn == 0:
            return None
        return 2 * self.tp / (2 * self.tp + self.fp + self.fn)

    def as_dict(self) -> dict:
        return {
            "precision": self.precision,
            "recall": self.recall,
            "f1": self.f1,
            "windows": self.windows,
            "tp": self.tp,
            "fp": self.fp,
            "fn": self.fn,
        }


def surface_distance_mm(predicted_points: np.ndarray, true_points: np.ndarray) -> tuple[float, float]:
    """(mean, max) symmetric nearest-point distance between two surfaces' face centres, in mm."""
    if len(predicted_points) == 0 or len(true_points) == 0:
        return float("nan"), float("nan")
    a = cKDTree(true_points).query(predicted_points)[0]
    b = cKDTree(predicted_points).query(true_points)[0]
    both = np.concatenate([a, b])
    return float(both.mean() * 1e3), float(both.max() * 1e3)


def fit_sphere(points: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Centre (m) and radius (m) of the sphere fitted to surface points (m) by linear least squares,
    |x|² = 2 c·x + k, r² = k + |c|²; None for fewer than 10 points or points that fix no sphere
    (all on a plane or a line). A reamed cavity's sphere, as a scan of a reamed socket is measured."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 10:
        return None
    origin = points.mean(axis=0)  # centred: the fit's conditioning no longer depends on where the bone lies
    local = points - origin
    design = np.column_stack([2.0 * local, np.ones(len(local))])
    solution, _, rank, _ = np.linalg.lstsq(design, (local * local).sum(axis=1), rcond=None)
    if rank < 4:
        return None
    centre, k = solution[:3], solution[3]
    radius_sq = k + float(centre @ centre)
    return (origin + centre, float(np.sqrt(radius_sq))) if radius_sq > 0 else None


#: the plate a seated reamer wears: cortical bone within this depth beyond the teeth's sphere …
PLATE_DEPTH_M = 1.5e-3
#: … and within this angle of the reamer's axis
PLATE_CONE_DEG = 45.0


def plate_left_mm3(
    centroids: np.ndarray,
    volumes: np.ndarray,
    plate: np.ndarray,
    alive: np.ndarray,
    centre: np.ndarray,
    axis: np.ndarray,
    teeth_radius_m: float,
) -> float:
    """Volume (mm³) of the ``plate`` elements (cortical) still ``alive`` just ahead of the teeth: centroid
    0–``PLATE_DEPTH_M`` beyond the teeth's sphere about ``centre``, within ``PLATE_CONE_DEG`` of ``axis``.
    A seated reamer wears this subchondral plate until it gives way (the benchmarks page)."""
    offset = centroids - centre
    distance = np.linalg.norm(offset, axis=1)
    ahead = offset @ axis >= np.cos(np.radians(PLATE_CONE_DEG)) * distance
    shell = (distance >= teeth_radius_m) & (distance <= teeth_radius_m + PLATE_DEPTH_M)
    return float(volumes[plate & alive & ahead & shell].sum()) * 1e9
