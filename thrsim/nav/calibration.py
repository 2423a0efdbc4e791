"""Frame calibration between an external tracker and a headset that both observe one target.

Per frame i, X_i = T_head←target,i · (T_tracker←target,i)⁻¹ estimates T_head←tracker. The
estimates are gated against a robust centre (rotation medoid, component-wise median
translation) with a median/MAD rule, since a plain mean is ruined by a few glitched frames
(measured: the docs' Benchmarks page, display calibration), then averaged: rotations with
scipy's ``Rotation.mean`` (Markley's quaternion average; Euler-angle averaging fails near
±180°), translations arithmetically. Pure numerics; metres and radians inside, degrees in the
report.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from thrsim.errors import ThrsimInputError
from thrsim.nav.rigid import check_pose, invert, make_pose

# 1.4826 · MAD estimates σ for Gaussian data; 3.5 σ keeps nearly all good frames.
_MAD_TO_SIGMA = 1.4826
# The medoid costs O(N²); a deterministic stride keeps it cheap for long recordings.
_MEDOID_SAMPLES = 400


class CalibrationRefused(ThrsimInputError):
    """Too few or too inconsistent samples; the message says which and by how much."""


@dataclass(frozen=True)
class FrameCalibration:
    transform: np.ndarray  # T_head←tracker
    used: int
    rejected: int
    rotation_residual_rms_deg: float
    translation_residual_rms_m: float
    inliers: np.ndarray  # boolean mask over the input frames

    def as_dict(self) -> dict:
        return {
            "transform": self.transform.tolist(),
            "used": self.used,
            "rejected": self.rejected,
            "rotation_residual_rms_deg": self.rotation_residual_rms_deg,
            "translation_residual_rms_mm": self.translation_residual_rms_m * 1e3,
        }


def _gate(distances: np.ndarray, k: float, floor: float) -> np.ndarray:
    median = np.median(distances)
    mad = np.median(np.abs(distances - median))
    return distances <= median + max(k * _MAD_TO_SIGMA * mad, floor)


def calibrate_frames(
    head_from_target: np.ndarray,
    tracker_from_target: np.ndarray,
    *,
    min_samples: int = 10,
    min_inlier_fraction: float = 0.6,
    gate_sigmas: float = 3.5,
    max_rotation_residual_deg: float = 5.0,
    max_translation_residual_m: float = 0.02,
) -> FrameCalibration:
    """T_head←tracker from paired observations (N×4×4 each) of one target."""
    head = np.asarray(head_from_target, dtype=float)
    tracker = np.asarray(tracker_from_target, dtype=float)
    if head.ndim != 3 or head.shape[1:] != (4, 4) or head.shape != tracker.shape:
        raise ThrsimInputError(f"calibration needs two N×4×4 pose arrays of equal length, got {head.shape} and {tracker.shape}")
    count = head.shape[0]
    if count < min_samples:
        raise CalibrationRefused(f"too few samples: {count} < {min_samples}")
    estimates = np.array(
        [
            check_pose(h, f"headset pose {i}") @ invert(check_pose(t, f"tracker pose {i}"))
            for i, (h, t) in enumerate(zip(head, tracker, strict=True))
        ]
    )

    rotations = Rotation.from_matrix(estimates[:, :3, :3])
    translations = estimates[:, :3, 3]
    sample = np.arange(0, count, max(1, count // _MEDOID_SAMPLES))
    pairwise = np.array([(rotations[sample] * rotations[i].inv()).magnitude() for i in sample])
    centre_rotation = rotations[sample[np.argmin(pairwise.sum(axis=1))]]
    centre_translation = np.median(translations, axis=0)

    angle_off = (rotations * centre_rotation.inv()).magnitude()
    shift_off = np.linalg.norm(translations - centre_translation, axis=1)
    # The floors stop noise-free data (MAD = 0) from rejecting every frame over rounding.
    inliers = _gate(angle_off, gate_sigmas, 1e-6) & _gate(shift_off, gate_sigmas, 1e-6)
    used = int(inliers.sum())
    if used < max(min_samples, min_inlier_fraction * count):
        raise CalibrationRefused(
            f"too inconsistent: only {used} of {count} frames agree (need {min_inlier_fraction:.0%} and at least {min_samples})"
        )

    rotation = rotations[inliers].mean()
    translation = translations[inliers].mean(axis=0)
    rotation_rms = float(np.degrees(np.sqrt(np.mean((rotations[inliers] * rotation.inv()).magnitude() ** 2))))
    translation_rms = float(np.sqrt(np.mean(np.sum((translations[inliers] - translation) ** 2, axis=1))))
    if rotation_rms > max_rotation_residual_deg:
        raise CalibrationRefused(f"too inconsistent: rotation residual {rotation_rms:.2f}° exceeds {max_rotation_residual_deg:g}°")
    if translation_rms > max_translation_residual_m:
        raise CalibrationRefused(
            f"too inconsistent: translation residual {translation_rms * 1e3:.1f} mm exceeds {max_translation_residual_m * 1e3:g} mm"
        )
    return FrameCalibration(
        transform=make_pose(rotation, translation),
        used=used,
        rejected=count - used,
        rotation_residual_rms_deg=rotation_rms,
        translation_residual_rms_m=translation_rms,
        inliers=inliers,
    )
