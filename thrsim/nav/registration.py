"""Landmark registration workflow: acquire pelvic landmarks one after another with a tracked probe.

A target is acquired when the probe tip stays within ``landmark_tolerance_mm`` of it, with the
probe and the pelvic reference frame both tracked, and the tip held still (within
``still_tolerance_mm`` of the mean tip position so far) for ``dwell_s``; the acquired point is the mean
tip position over the dwell, which averages tracker noise. Each update returns events for the
trainee's feedback (sound, colour). Once every target is acquired, the synthetic pelvis model's
landmarks are fitted rigidly to the acquired points and the APP is computed from the acquired
ASIS and pubic tubercles. Pure numerics; times in seconds, positions in metres in the reference
frame.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from thrsim.config import TrackingVolumeConfig
from thrsim.errors import ThrsimInputError
from thrsim.nav.anatomy import AppFrame, app_frame
from thrsim.nav.rigid import RigidFit, rigid_fit
from thrsim.nav.tracking import Visibility

EVENT_KINDS: tuple[str, ...] = ("target", "acquired", "tracking_lost", "tracking_regained", "completed")


@dataclass(frozen=True)
class RegistrationEvent:
    kind: str  # one of EVENT_KINDS
    time_s: float
    landmark: str | None = None
    detail: str = ""  # for tracking_lost: which tool and why (outside_volume, angle, occluded)
    error_m: float | None = None  # for acquired: distance from the acquired point to the target

    def as_dict(self) -> dict:
        return {"kind": self.kind, "time_s": self.time_s, "landmark": self.landmark, "detail": self.detail, "error_m": self.error_m}


@dataclass(frozen=True)
class RegistrationResult:
    """The model-to-reference fit (``fit.pose`` = T_reference←model) and the APP from acquired points."""

    fit: RigidFit
    app: AppFrame
    acquired: dict[str, np.ndarray]

    @property
    def rms_residual_m(self) -> float:
        return self.fit.rms


class LandmarkRegistration:
    """Step through ``targets`` (name → position in the reference frame, m) in order."""

    def __init__(self, targets: Mapping[str, object], config: TrackingVolumeConfig = TrackingVolumeConfig()):
        if len(targets) < 3:
            raise ThrsimInputError(f"registration needs at least 3 landmark targets, got {len(targets)}")
        self.targets = {name: np.asarray(p, dtype=float) for name, p in targets.items()}
        for name, point in self.targets.items():
            if point.shape != (3,) or not np.all(np.isfinite(point)):
                raise ThrsimInputError(f"landmark target {name!r} must be a finite 3-vector")
        self.config = config
        self.acquired: dict[str, np.ndarray] = {}
        self._order = list(self.targets)
        self._dwell: list[np.ndarray] = []
        self._dwell_start = 0.0
        self._lost = False
        self._started = False

    @property
    def current_target(self) -> str | None:
        return self._order[len(self.acquired)] if len(self.acquired) < len(self._order) else None

    @property
    def done(self) -> bool:
        return self.current_target is None

    def update(
        self,
        time_s: float,
        probe_tip: np.ndarray | None,
        probe: Visibility,
        reference: Visibility,
    ) -> list[RegistrationEvent]:
        """Feed one tracker frame: the probe tip in the reference frame (None when not measured)."""
        events: list[RegistrationEvent] = []
        if not self._started:
            self._started = True
            events.append(RegistrationEvent("target", time_s, self.current_target))
        name = self.current_target
        if name is None:  # done
            return events
        blocked = [f"{tool} {v.reason}" for tool, v in (("probe", probe), ("reference", reference)) if not v.tracked]
        if blocked or probe_tip is None:
            self._dwell = []
            if probe.reason == "missing":
                return events  # a probe not in use (none picked up yet, or put down) has no tracking to lose
            if not self._lost:
                self._lost = True
                events.append(RegistrationEvent("tracking_lost", time_s, name, ", ".join(blocked) or "probe not measured"))
            return events
        if self._lost:
            self._lost = False
            events.append(RegistrationEvent("tracking_regained", time_s, name))

        tip = np.asarray(probe_tip, dtype=float)
        target = self.targets[name]
        if np.linalg.norm(tip - target) > self.config.landmark_tolerance_mm * 1e-3:
            self._dwell = []
            return events
        # Against the running mean, not the first sample: one noisy sample must not restart the dwell.
        if not self._dwell or np.linalg.norm(tip - np.mean(self._dwell, axis=0)) > self.config.still_tolerance_mm * 1e-3:
            self._dwell, self._dwell_start = [tip], time_s
            return events
        self._dwell.append(tip)
        if time_s - self._dwell_start < self.config.dwell_s:
            return events

        point = np.mean(self._dwell, axis=0)
        self.acquired[name] = point
        self._dwell = []
        events.append(RegistrationEvent("acquired", time_s, name, error_m=float(np.linalg.norm(point - target))))
        events.append(RegistrationEvent("completed", time_s) if self.done else RegistrationEvent("target", time_s, self.current_target))
        return events

    def result(self, model_landmarks: Mapping[str, object], side: str = "right", plane: str = "standard") -> RegistrationResult:
        """Fit ``model_landmarks`` (same names, model frame) to the acquired points; APP from them."""
        if not self.done:
            raise ThrsimInputError(f"registration incomplete: {len(self.acquired)} of {len(self._order)} landmarks acquired")
        missing = [name for name in self.acquired if name not in model_landmarks]
        if missing:
            raise ThrsimInputError(f"model lacks acquired landmarks: {', '.join(missing)}")
        names = list(self.acquired)
        model = np.array([np.asarray(model_landmarks[n], dtype=float) for n in names])
        fit = rigid_fit(model, np.array([self.acquired[n] for n in names]))
        return RegistrationResult(fit=fit, app=app_frame(self.acquired, side=side, plane=plane), acquired=dict(self.acquired))
