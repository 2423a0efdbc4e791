"""Rigid transforms: validation, inversion and the least-squares (Kabsch) fit of point sets.

Poses are 4×4 homogeneous matrices ``T_a←b`` mapping coordinates in frame b to frame a, in
metres. Pure numerics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from thrsim.errors import ThrsimInputError

# float32 on the wire (OpenIGTLink TRANSFORM) keeps rotations orthonormal to ~1e-6; a looser
# bound would let scaled or sheared matrices through as poses.
_ORTHONORMAL_TOLERANCE = 1e-3


def check_pose(pose: object, what: str = "pose") -> np.ndarray:
    """Return ``pose`` as a float 4×4 rigid transform, or raise ThrsimInputError saying why not."""
    try:
        matrix = np.asarray(pose, dtype=float)
    except (TypeError, ValueError):
        raise ThrsimInputError(f"{what} is not a 4x4 matrix of numbers") from None
    if matrix.shape != (4, 4):
        raise ThrsimInputError(f"{what} must be 4x4, got shape {matrix.shape}")
    if not np.all(np.isfinite(matrix)):
        raise ThrsimInputError(f"{what} contains NaN or infinite values")
    if not np.allclose(matrix[3], (0.0, 0.0, 0.0, 1.0), atol=1e-6):
        raise ThrsimInputError(f"{what} last row must be 0 0 0 1, got {matrix[3].tolist()}")
    rotation = matrix[:3, :3]
    if np.abs(rotation.T @ rotation - np.eye(3)).max() > _ORTHONORMAL_TOLERANCE or np.linalg.det(rotation) < 0:
        raise ThrsimInputError(f"{what} rotation part is not a proper rotation (scaled, sheared or mirrored)")
    return matrix


def make_pose(rotation: np.ndarray | Rotation, translation: np.ndarray) -> np.ndarray:
    """4×4 pose from a rotation (matrix or scipy Rotation) and a translation."""
    pose = np.eye(4)
    pose[:3, :3] = rotation.as_matrix() if isinstance(rotation, Rotation) else rotation
    pose[:3, 3] = translation
    return pose


def invert(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform without a general matrix inverse."""
    rotation = pose[:3, :3]
    inverse = np.eye(4)
    inverse[:3, :3] = rotation.T
    inverse[:3, 3] = -rotation.T @ pose[:3, 3]
    return inverse


def transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    return np.asarray(points, dtype=float) @ pose[:3, :3].T + pose[:3, 3]


@dataclass(frozen=True)
class RigidFit:
    """``pose`` maps source points onto target points; residuals are per point, in metres."""

    pose: np.ndarray
    residuals: np.ndarray

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))


def rigid_fit(source: np.ndarray, target: np.ndarray) -> RigidFit:
    """Least-squares rigid transform (Kabsch, via scipy) taking ``source`` (N×3) onto ``target``."""
    source = np.asarray(source, dtype=float)
    target = np.asarray(target, dtype=float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3:
        raise ThrsimInputError(f"rigid fit needs two N×3 point sets of equal size, got {source.shape} and {target.shape}")
    if source.shape[0] < 3:
        raise ThrsimInputError(f"rigid fit needs at least 3 points, got {source.shape[0]}")
    if not (np.all(np.isfinite(source)) and np.all(np.isfinite(target))):
        raise ThrsimInputError("rigid fit points contain NaN or infinite values")
    source_centre, target_centre = source.mean(axis=0), target.mean(axis=0)
    rotation, _ = Rotation.align_vectors(target - target_centre, source - source_centre)
    pose = make_pose(rotation, target_centre - rotation.apply(source_centre))
    residuals = np.linalg.norm(transform_points(pose, source) - target, axis=1)
    return RigidFit(pose=pose, residuals=residuals)
