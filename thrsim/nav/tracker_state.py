"""Navigation state from streamed tracker poses and force readings (pure; the server feeds it).

Device names: ``ReamerToReference`` (reamer in the pelvic reference frame),
``ReferenceToTracker`` and ``ReamerToTracker`` (both in the camera frame), ``ProbeToReference``.
The reamer's tool frame has its local −z along the reamer axis D (from the reamer into the
bone), so the cup axis out of the acetabulum is the tool's local +z. Landmarks are in the
reference frame; with none given, the synthetic pelvis stands in with its model frame as the
reference frame.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Generic, TypeVar

import numpy as np

from thrsim.config import SafeZone, Side, TrackingVolumeConfig
from thrsim.errors import ThrsimInputError
from thrsim.nav.anatomy import AppFrame, angles_in_frame, app_frame
from thrsim.nav.pelvis import synthetic_pelvis_landmarks
from thrsim.nav.rigid import check_pose, invert
from thrsim.nav.safe_zone import safe_zone_status
from thrsim.nav.tracking import REAMER, REFERENCE_FRAME, TrackingCamera

REAMER_TO_REFERENCE = "ReamerToReference"
REAMER_TO_TRACKER = "ReamerToTracker"
REFERENCE_TO_TRACKER = "ReferenceToTracker"
CUP_AXIS_IN_REAMER = np.array([0.0, 0.0, 1.0])
Reading = TypeVar("Reading")

_TOOLS_SEEN_BY_CAMERA = {"Reamer": (REAMER_TO_TRACKER, REAMER), "Reference": (REFERENCE_TO_TRACKER, REFERENCE_FRAME)}


@dataclass
class _Stamped(Generic[Reading]):
    value: Reading
    time_s: float


@dataclass
class TrackerState:
    """Latest poses and force, and the navigation state they imply at a given time."""

    side: Side = "right"
    landmarks: Mapping[str, object] | None = None
    zone: SafeZone = SafeZone()
    tracking: TrackingVolumeConfig = TrackingVolumeConfig()
    stale_after_s: float = 0.5
    poses: dict[str, _Stamped[np.ndarray]] = field(default_factory=dict)
    force: _Stamped[float] | None = None

    def __post_init__(self) -> None:
        landmarks = synthetic_pelvis_landmarks(self.side) if self.landmarks is None else self.landmarks
        self.app: AppFrame = app_frame(landmarks, side=self.side)
        # The camera sits at the tracker's origin, so *ToTracker poses are already camera-frame.
        self.camera = TrackingCamera(self.tracking, seed=None)

    def update_pose(self, device: str, pose: np.ndarray, time_s: float) -> None:
        """Store a pose (4×4, metres); raises ThrsimInputError for a NaN or non-rigid one."""
        self.poses[device] = _Stamped(check_pose(pose, f"{device} pose"), time_s)

    def update_force(self, values: np.ndarray, time_s: float) -> float:
        """Store a force reading in newtons: one value, or a vector whose magnitude is used; that force."""
        values = np.asarray(values, dtype=float)
        if values.size == 0 or not np.all(np.isfinite(values)):
            raise ThrsimInputError("force reading is empty or not finite")
        with np.errstate(over="ignore"):
            newton = float(values[0]) if values.size == 1 else float(np.linalg.norm(values))
        if not np.isfinite(newton):  # finite components whose magnitude overflows (1e300 N each)
            raise ThrsimInputError(f"force reading's magnitude overflows: components up to {np.abs(values).max():.3g} N")
        self.force = _Stamped(newton, time_s)
        return newton

    def _fresh(self, device: str, time_s: float) -> np.ndarray | None:
        stamped = self.poses.get(device)
        return stamped.value if stamped is not None and time_s - stamped.time_s <= self.stale_after_s else None

    def reamer_to_reference(self, time_s: float) -> np.ndarray | None:
        direct = self._fresh(REAMER_TO_REFERENCE, time_s)
        if direct is not None:
            return direct
        reamer, reference = self._fresh(REAMER_TO_TRACKER, time_s), self._fresh(REFERENCE_TO_TRACKER, time_s)
        return None if reamer is None or reference is None else invert(reference) @ reamer

    def tracking_status(self, time_s: float) -> dict[str, str]:
        """Per tool: tracked / outside_volume / angle (from camera-frame poses), stale, or missing."""
        status = {}
        for tool, (device, geometry) in _TOOLS_SEEN_BY_CAMERA.items():
            pose = self._fresh(device, time_s)
            if pose is not None:
                status[tool] = self.camera.observe(geometry, pose).reason
            elif tool == "Reamer" and self._fresh(REAMER_TO_REFERENCE, time_s) is not None:
                status[tool] = "tracked"
            elif device in self.poses or (tool == "Reamer" and REAMER_TO_REFERENCE in self.poses):
                status[tool] = "stale"
            else:
                status[tool] = "missing"
        return status

    def state(self, time_s: float) -> dict:
        """The NavigationState payload (JSON-ready; degrees and millimetres at this edge)."""
        state: dict = {
            "side": self.side,
            "definition": "radiographic",
            "inclination_deg": None,
            "anteversion_deg": None,
            "operative_deg": None,
            "anatomic_deg": None,
            "in_safe_zone": None,
            "distance_to_zone_deg": None,
            "ray_colour": None,
            "reamer_position_mm": None,
            "tracking": self.tracking_status(time_s),
            "force_n": None if self.force is None else self.force.value,
            "force_age_s": None if self.force is None else round(time_s - self.force.time_s, 4),
            "note": "",
        }
        pose = self.reamer_to_reference(time_s)
        if pose is None:
            state["note"] = "no fresh reamer pose"
            return state
        cup_axis = pose[:3, :3] @ CUP_AXIS_IN_REAMER
        try:
            inclination, anteversion = angles_in_frame(cup_axis, self.app, "radiographic")
            operative = angles_in_frame(cup_axis, self.app, "operative")
            anatomic = angles_in_frame(cup_axis, self.app, "anatomic")
        except ThrsimInputError as error:
            state["note"] = str(error)
            return state
        zone = safe_zone_status(inclination, anteversion, self.zone)
        state.update(
            inclination_deg=inclination,
            anteversion_deg=anteversion,
            operative_deg=list(operative),
            anatomic_deg=list(anatomic),
            in_safe_zone=zone.inside,
            distance_to_zone_deg=zone.distance_deg,
            ray_colour=zone.colour,
            reamer_position_mm=(pose[:3, 3] * 1e3).tolist(),
        )
        return state
