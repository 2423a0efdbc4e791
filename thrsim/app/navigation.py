"""The navigation-skills trainer: the thesis's first system [3.1–3.3] as one session's logic.

A trainee keeps the markers in the IR camera's tracking volume, acquires 27 pelvic landmarks
with a tracked probe, gets the anterior pelvic plane (APP) from them, and aims the reamer with a
ray coloured by the Lewinnek safe zone; a guided step calibrates the display against the
tracker. Tools are driven by a real tracker (OpenIGTLink poses) or by the page's controls on a
synthetic pelvis. Poses are in the pelvic reference array's frame; the pelvis model sits in it
at ``model_to_reference`` and the page draws the model frame, placed by the registration once
it exists. Numerics come from :mod:`thrsim.nav`; this module orchestrates them. No I/O.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from thrsim.app import controls as c
from thrsim.config import SafeZone, TrackingVolumeConfig
from thrsim.errors import ThrsimInputError
from thrsim.nav.anatomy import (
    DEFINITIONS,
    angles_from_local,
    angles_in_frame,
    app_frame,
    local_axis_from_angles,
)
from thrsim.nav.bone_frame import check_side, on_side, other_side
from thrsim.nav.calibration import calibrate_frames
from thrsim.nav.pelvis import (
    ACETABULUM_RIM_RADIUS,
    acetabulum_centre,
    synthetic_pelvis_landmarks,
)
from thrsim.nav.phantom import Phantom, headset_from_model
from thrsim.nav.registration import LandmarkRegistration, RegistrationResult
from thrsim.nav.rigid import check_pose, invert, make_pose, transform_points
from thrsim.nav.safe_zone import safe_zone_status
from thrsim.nav.tracker_state import CUP_AXIS_IN_REAMER
from thrsim.nav.tracking import (
    PROBE,
    REAMER,
    REASONS,
    REFERENCE_FRAME,
    Box,
    TrackingCamera,
    Visibility,
    look_at,
)
from thrsim.session.navigation import NavigationRecord, write_navigation

TOOLS = {"Reference": REFERENCE_FRAME, "Probe": PROBE, "Reamer": REAMER}
# Tracker device → (tool, frame the pose is given in): the TRANSFORM device names trackers send
# (thrsim.config.KNOWN_TRACKER_DEVICES).
DEVICES = {
    "ReferenceToTracker": ("Reference", "tracker"),
    "ProbeToReference": ("Probe", "reference"),
    "ProbeToTracker": ("Probe", "tracker"),
    "ReamerToReference": ("Reamer", "reference"),
    "ReamerToTracker": ("Reamer", "tracker"),
}
# Reasons a tool is not tracked, beyond the camera model's: no pose for too long, or never one.
TOOL_STATES: tuple[str, ...] = REASONS + ("stale", "missing")

# Default camera: at the foot end, lateral and anterior of the operated hip, looking at it, so
# that the reference array, the probe and a reamer inside the safe zone all face it (< 45°).
DEFAULT_CAMERA = {"azimuth_deg": 50.0, "elevation_deg": -37.0, "distance_mm": 1600.0}
#: where the page's reamer starts (radiographic): outside the zone, in view, so aiming is the trainee's
DEFAULT_REAMER = {"inclination_deg": 60.0, "anteversion_deg": 10.0}
# A hand holding a probe on a landmark: a steady offset within the acquisition tolerance, and a
# tremor well inside the still tolerance (so a touch is acquired after the dwell). The offset is
# shortened to a fraction of the tolerance: a touch from the page is meant to be on the landmark,
# and an unbounded Gaussian would leave one touch in about a thousand outside it for good.
_HAND_OFFSET_SD_M = 1.2e-3
_HAND_OFFSET_MAX_FRACTION = 0.6
_HAND_TREMOR_SD_M = 0.2e-3
# Noise of the display calibration step: the headset's view of the image target (rotation
# noise is multiplied by the ~1.6 m lever arm to the IR camera, so it is kept at 0.3°) and the
# tracker's (0.25 mm RMS); it averages one second of paired samples at 60 Hz [3.3].
_HEADSET_NOISE = (math.radians(0.3), 2e-3)
_TRACKER_NOISE_M = 0.25e-3
CALIBRATION_SAMPLES = int(TrackingVolumeConfig().rate_hz)
# The image target both the tracker and the display observe, on the drape beside the pelvis.
_CALIBRATION_TARGET_MODEL = np.array([0.0, 0.12, -0.02])
# A surgeon's arm and shoulder: a box between the camera and the tools, on the camera side.
_OCCLUDER_HALF_SIZE = np.array([0.1, 0.1, 0.1])
_OCCLUDER_STANDOFF_M = 0.45


def _spherical(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    azimuth, elevation = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation)])


def _frame_with_z(z_axis: np.ndarray, hint: np.ndarray) -> np.ndarray:
    """A rotation whose third column is ``z_axis`` and second is ``hint`` made orthogonal to it."""
    z_axis = z_axis / np.linalg.norm(z_axis)
    y_axis = hint - (hint @ z_axis) * z_axis
    if np.linalg.norm(y_axis) < 1e-6:
        y_axis = np.cross(z_axis, [1.0, 0.0, 0.0])
    y_axis /= np.linalg.norm(y_axis)
    return np.column_stack([np.cross(y_axis, z_axis), y_axis, z_axis])


def _random_rotation_small(rng: np.random.Generator, sd_rad: float) -> np.ndarray:
    return Rotation.from_rotvec(rng.normal(0.0, sd_rad, 3)).as_matrix()


@dataclass
class _ToolPose:
    pose: np.ndarray  # T_reference←tool, metres
    source: str  # "page" or "tracker"
    time_s: float


@dataclass
class NavigationLog:
    """What the report needs, appended at every step and event until the session is saved."""

    # One entry per step, in compact buffers (a long session has tens of thousands of steps).
    trace_time: array = field(default_factory=lambda: array("d"))
    trace_angles: array = field(default_factory=lambda: array("d"))  # RI, RA, distance per step (NaN unknown)
    trace_phase: array = field(default_factory=lambda: array("b"))  # 0 registering, 1 aiming
    trace_tools: array = field(default_factory=lambda: array("B"))  # TOOL_STATES index per tool per step
    events: list[dict] = field(default_factory=list)
    calibrations: list[dict] = field(default_factory=list)
    confirmations: list[dict] = field(default_factory=list)
    retakes: dict[str, int] = field(default_factory=dict)
    target_started: dict[str, float] = field(default_factory=dict)
    landmark_time_s: dict[str, float] = field(default_factory=dict)


class NavigationTrainer:
    """One trainee's navigation session. Feed it controls, tracker poses and steps; read its state."""

    mode = "navigation"

    def __init__(
        self,
        side: str = "right",
        seed: int = 0,
        zone: SafeZone = SafeZone(),
        tracking: TrackingVolumeConfig = TrackingVolumeConfig(),
        stale_after_s: float = 0.5,
        reamer_start: dict[str, float] = DEFAULT_REAMER,
        phantom: Phantom | None = None,
    ):
        self.seed = seed
        self.phantom = phantom  # a lab's physical pelvis: its marker array is the reference (None: the simulated one's)
        self.reamer_start = dict(reamer_start)
        self.zone = zone
        self.tracking = tracking
        self.stale_after_s = stale_after_s
        self.rng = np.random.default_rng(seed)
        self.definition = "radiographic"
        self.occluder = False
        self.log = NavigationLog()
        self.viewer_pose: np.ndarray | None = None
        self.force_n: float | None = None
        self._pending_events: list[dict] = []
        self._calibration: dict = {"state": "idle", "samples": 0, "message": "", "result": None}
        self._calibration_pairs: tuple[list, list] = ([], [])
        # the headset's calibration (the controller seated on the target) and its result, T_headset←tracker
        self._headset: dict = {"state": "idle", "samples": 0, "message": "", "result": None}
        self._headset_pairs: tuple[list, list] = ([], [])
        self.headset_from_tracker: np.ndarray | None = None
        self._set_side(side, time_s=0.0)

    # ---- set-up -----------------------------------------------------------------------------

    def _set_side(self, side: str, time_s: float) -> None:
        self.side = side = check_side(side)
        self.model_landmarks = synthetic_pelvis_landmarks(side)
        self.true_app_model = app_frame(self.model_landmarks, side=side)
        self.acetabulum_model = acetabulum_centre(side)
        crest = self.model_landmarks[f"iliac_tubercle_{side}"] + np.array([0.0, 0.02, 0.03])
        facing = on_side(_spherical(DEFAULT_CAMERA["azimuth_deg"], DEFAULT_CAMERA["elevation_deg"]), side)
        camera = dict(DEFAULT_CAMERA, azimuth_deg=math.degrees(math.atan2(facing[1], facing[0])))
        # T_model←array: the array on the crest, its markers facing the default camera.
        array_in_model = make_pose(_frame_with_z(facing, np.array([0.0, 0.0, 1.0])), crest)
        self.model_to_reference = invert(array_in_model) if self.phantom is None else self.phantom.reference_from_model
        self.targets = {name: transform_points(self.model_to_reference, p[None])[0] for name, p in self.model_landmarks.items()}
        self._place_page_camera(camera)
        self.true_app = app_frame(self.targets, side=side)
        self.tools: dict[str, _ToolPose] = {"Reference": _ToolPose(np.eye(4), "page", time_s)}
        self.tracker_camera: _ToolPose | None = None
        self._reamer_angles = dict(self.reamer_start)
        self._set_page_reamer(time_s)
        self._probe_tip: np.ndarray | None = None  # where the page's hand holds the probe tip (reference frame, m)
        self._restart_registration(time_s)

    def _restart_registration(self, time_s: float) -> None:
        self.registration = LandmarkRegistration(self.targets, self.tracking)
        self.result: RegistrationResult | None = None
        self.app = self.true_app
        self.app_source = "model"
        self.scene_to_reference = self.model_to_reference
        self.log.target_started = {}
        self.log.landmark_time_s = {}
        self.log.retakes = {}

    # ---- geometry helpers ---------------------------------------------------------------------

    @property
    def camera_pose(self) -> np.ndarray:
        """T_reference←camera: from the tracker when it reports the reference array, else the page's."""
        return self._page_camera_pose if self.tracker_camera is None else self.tracker_camera.pose

    def _place_page_camera(self, spherical: dict) -> None:
        self.camera_spherical = spherical
        self._page_camera_pose = self._camera_from_spherical()

    def _camera_from_spherical(self) -> np.ndarray:
        s = self.camera_spherical
        target = transform_points(self.model_to_reference, self.acetabulum_model[None])[0]
        direction = self.model_to_reference[:3, :3] @ _spherical(s["azimuth_deg"], s["elevation_deg"])
        up = self.model_to_reference[:3, :3] @ np.array([0.0, 0.0, 1.0])
        return look_at(target + s["distance_mm"] * 1e-3 * direction, target, up)

    def _occluders(self) -> list[Box]:
        if not self.occluder:
            return []
        camera = self.camera_pose[:3, 3]
        field_centre = np.mean([held.pose[:3, 3] for held in self.tools.values()], axis=0)
        centre = field_centre + _OCCLUDER_STANDOFF_M * (camera - field_centre) / np.linalg.norm(camera - field_centre)
        return [Box(centre - _OCCLUDER_HALF_SIZE, centre + _OCCLUDER_HALF_SIZE)]

    def reamer_pose(self, inclination_deg: float, anteversion_deg: float) -> np.ndarray:
        """T_reference←reamer of a reamer in the acetabulum at radiographic angles in the true APP
        (what a tracker would send as ``ReamerToReference``)."""
        axis_model = self.true_app_model.to_world(local_axis_from_angles(inclination_deg, anteversion_deg))
        head = self.acetabulum_model  # the reamer sits in the acetabulum
        rotation = _frame_with_z(axis_model, np.array([0.0, 0.0, 1.0]))
        origin = head - rotation @ REAMER.tip  # the head centre is the tool's tip
        return self.model_to_reference @ make_pose(rotation, origin)

    def _set_page_reamer(self, time_s: float) -> None:
        pose = self.reamer_pose(self._reamer_angles["inclination_deg"], self._reamer_angles["anteversion_deg"])
        self.tools["Reamer"] = _ToolPose(pose, "page", time_s)

    def _set_page_probe(self, tip: np.ndarray, time_s: float) -> None:
        self._probe_tip = tip
        facing = self.model_to_reference[:3, :3] @ _spherical(self.camera_spherical["azimuth_deg"], self.camera_spherical["elevation_deg"])
        outward = tip - np.mean(list(self.targets.values()), axis=0)
        # PROBE.tip is along the tool's −y: the handle (+y) points away from the pelvis.
        rotation = _frame_with_z(facing, outward)
        tremor = self.rng.normal(0.0, _HAND_TREMOR_SD_M, 3)
        origin = tip + tremor - rotation @ PROBE.tip
        self.tools["Probe"] = _ToolPose(make_pose(rotation, origin), "page", time_s)

    # ---- inputs -------------------------------------------------------------------------------

    def apply_pose(self, device: str, pose: np.ndarray, time_s: float) -> None:
        """A tracker pose (4×4, metres); devices this trainer does not use are ignored."""
        if device not in DEVICES:
            return
        pose = check_pose(pose, f"{device} pose")
        tool, frame = DEVICES[device]
        if tool == "Reference":
            # The tracker sees the reference array: that fixes where the camera is.
            self.tracker_camera = _ToolPose(invert(pose), "tracker", time_s)
            self.tools["Reference"] = _ToolPose(np.eye(4), "tracker", time_s)
            return
        if frame == "tracker":
            if self.tracker_camera is None:
                return  # no reference seen yet: the pose cannot be put in the pelvis frame
            pose = self.tracker_camera.pose @ pose
        self.tools[tool] = _ToolPose(pose, "tracker", time_s)

    def apply_force(self, newton: float, time_s: float) -> None:
        self.force_n = float(newton)

    def apply_control(self, control: c._Control, time_s: float) -> str:
        """Act on one validated control; returns a short acknowledgement. Refusals raise ThrsimInputError."""
        if isinstance(control, c.CameraControl):
            self._place_page_camera(
                {"azimuth_deg": control.azimuth_deg, "elevation_deg": control.elevation_deg, "distance_mm": control.distance_mm}
            )
            return "camera moved"
        if isinstance(control, c.ReamerControl):
            self._reamer_angles = {"inclination_deg": control.inclination_deg, "anteversion_deg": control.anteversion_deg}
            self._set_page_reamer(time_s)
            return "reamer steered"
        if isinstance(control, c.ProbeControl):
            return self._probe(control, time_s)
        if isinstance(control, c.RegistrationControl):
            return self._registration_control(control.action, time_s)
        if isinstance(control, c.DefinitionControl):
            self.definition = control.value
            return f"angles shown as {control.value}"
        if isinstance(control, c.SideControl):
            if control.value != self.side:
                self._set_side(control.value, time_s)
                self._event(time_s, "side_changed", detail=control.value)
            return f"{control.value} hip"
        if isinstance(control, c.OccluderControl):
            self.occluder = control.present
            return "occluder " + ("placed" if control.present else "removed")
        if isinstance(control, c.ViewerControl):
            pose = np.array(control.pose, dtype=float).reshape(4, 4)
            self.viewer_pose = check_pose(pose, "viewer pose")
            return "viewer pose"
        if isinstance(control, c.CalibrationControl):
            if self.viewer_pose is None:
                raise ThrsimInputError("calibration needs the display's pose first (the page sends it when the view moves)")
            self._calibration = {"state": "sampling", "samples": 0, "message": "hold the view still", "result": None}
            self._calibration_pairs = ([], [])
            self._event(time_s, "calibration_started")
            return "calibration started"
        if isinstance(control, c.HeadsetControl):
            return self._headset_control(control, time_s)
        if isinstance(control, c.ReamerAxisControl):
            return self._aim_reamer(np.array(control.axis, dtype=float), time_s)
        if isinstance(control, c.ConfirmControl):
            return self._confirm(time_s)
        raise ThrsimInputError(f"{control.type} is not a navigation-trainer control")

    def _aim_reamer(self, axis_scene: np.ndarray, time_s: float) -> str:
        """The page's reamer along a shaft direction (scene frame, out of the socket): a headset's
        controller held as the reamer. Aimed into the pelvis, or beyond the angles the page offers,
        it stops at the nearest it can take."""
        local = self.true_app_model.to_local(axis_scene / np.linalg.norm(axis_scene))
        local[0] = max(local[0], 0.0)  # lateral: a shaft pointing into the pelvis stops in the APP's sagittal plane
        local /= max(float(np.linalg.norm(local)), 1e-9)
        inclination, anteversion = angles_from_local(local)
        self._reamer_angles = {"inclination_deg": min(inclination, 90.0), "anteversion_deg": anteversion}
        self._set_page_reamer(time_s)
        return "reamer aimed"

    def _headset_target(self) -> np.ndarray:
        """T_reference←target: the cradle the controller sits in while the headset is calibrated."""
        if self.phantom is not None:
            return self.phantom.target
        return self.model_to_reference @ make_pose(np.eye(3), _CALIBRATION_TARGET_MODEL)

    def _headset_control(self, control: c.HeadsetControl, time_s: float) -> str:
        """The headset's calibration: ``start`` it, one ``target`` pose per headset frame (the
        controller's grip on the target, T_headset←target), ``clear`` the result. Each target pose is
        paired with the tracker's view of the same target; once a second's worth is in, the robust
        average gives T_headset←tracker (the display calibration of the thesis's §3.3)."""
        if control.action == "clear":
            self.headset_from_tracker = None
            self._headset = {"state": "idle", "samples": 0, "message": "", "result": None}
            return "headset calibration cleared"
        if control.action == "start":
            self._headset = {"state": "sampling", "samples": 0, "message": "hold the controller still on the target", "result": None}
            self._headset_pairs = ([], [])
            self._event(time_s, "headset_calibration_started")
            return "headset calibration started"
        if self._headset["state"] != "sampling":
            return "not calibrating the headset"
        heads, trackers = self._headset_pairs
        heads.append(check_pose(np.array(control.pose, dtype=float).reshape(4, 4), "headset target pose"))
        trackers.append(invert(self.camera_pose) @ self._headset_target())
        self._headset["samples"] = len(heads)
        if len(heads) < CALIBRATION_SAMPLES:
            return "headset sample"
        try:
            result = calibrate_frames(np.array(heads), np.array(trackers))
        except ThrsimInputError as error:
            self._headset.update(state="refused", message=str(error), result=None)
            self._event(time_s, "headset_calibration_refused", detail=str(error))
            return "headset calibration refused"
        self.headset_from_tracker = result.transform
        summary = result.as_dict()
        summary.pop("transform")
        self._headset.update(state="done", message="calibrated", result=summary)
        detail = f"{summary['rotation_residual_rms_deg']:.2f}° / {summary['translation_residual_rms_mm']:.2f} mm"
        self._event(time_s, "headset_calibrated", detail=detail)
        return "headset calibrated"

    def _headset_state(self) -> dict:
        """The headset's calibration and, once done, where it draws the scene (T_headset←scene, row-major):
        it follows the tracker's view of the reference array, so the bone stays on a phantom that moves."""
        placement = None
        if self.headset_from_tracker is not None:
            pose = headset_from_model(self.headset_from_tracker, invert(self.camera_pose), self.scene_to_reference)
            placement = pose.ravel().tolist()
        return {**self._headset, "needed": CALIBRATION_SAMPLES, "placement": placement}

    def _probe(self, control: c.ProbeControl, time_s: float) -> str:
        if control.action == "lift":
            self._probe_tip = None
            self.tools.pop("Probe", None)
            return "probe lifted"
        if control.action == "place":
            tip = transform_points(self.scene_to_reference, np.array(control.tip_mm)[None] * 1e-3)[0]
            self._set_page_probe(tip, time_s)
            return "probe placed"
        name = control.landmark or self.registration.current_target
        if name is None:
            raise ThrsimInputError("registration is complete: no landmark left to touch")
        if name not in self.targets:
            raise ThrsimInputError(f"unknown landmark {name!r}")
        self._set_page_probe(self.targets[name] + self._hand_offset(), time_s)
        return f"probe on {name}"

    def _hand_offset(self) -> np.ndarray:
        offset = self.rng.normal(0.0, _HAND_OFFSET_SD_M, 3)
        limit_m = _HAND_OFFSET_MAX_FRACTION * self.tracking.landmark_tolerance_mm * 1e-3
        return offset * min(1.0, limit_m / max(float(np.linalg.norm(offset)), 1e-12))

    def _registration_control(self, action: str, time_s: float) -> str:
        if action == "restart":
            self._restart_registration(time_s)
            self._event(time_s, "registration_restarted")
            first = self.registration.current_target
            self._event(time_s, "target", landmark=first)
            if first is not None:
                self.log.target_started[first] = time_s
            return "registration restarted"
        if not self.registration.acquired:
            raise ThrsimInputError("no landmark acquired yet: nothing to retake")
        name = list(self.registration.acquired)[-1]
        del self.registration.acquired[name]  # the workflow's target is the first not acquired
        self.result, self.app, self.app_source, self.scene_to_reference = None, self.true_app, "model", self.model_to_reference
        self.log.retakes[name] = self.log.retakes.get(name, 0) + 1
        self.log.target_started[name] = time_s
        self._event(time_s, "retake", landmark=name)
        self._event(time_s, "target", landmark=name)
        return f"retake {name}"

    def _confirm(self, time_s: float) -> str:
        angles = self.reamer_angles_now(time_s)
        if self.result is None:
            raise ThrsimInputError("complete the landmark registration before confirming the cup orientation")
        if angles is None:
            raise ThrsimInputError("the reamer is not tracked: cannot confirm its orientation")
        inclination, anteversion = angles["radiographic"]
        zone = safe_zone_status(inclination, anteversion, self.zone)
        record = {
            "time_s": time_s,
            "inclination_deg": inclination,
            "anteversion_deg": anteversion,
            "inside": zone.inside,
            "distance_deg": zone.distance_deg,
        }
        self.log.confirmations.append(record)
        self._event(time_s, "cup_confirmed", detail=f"{inclination:.1f}/{anteversion:.1f}", value=zone.distance_deg)
        return f"cup orientation confirmed at {inclination:.1f}° / {anteversion:.1f}°"

    def _event(self, time_s: float, kind: str, landmark: str | None = None, detail: str = "", value: float | None = None) -> None:
        event = {"time_s": time_s, "kind": kind, "landmark": landmark, "detail": detail, "value": value}
        self.log.events.append(event)
        self._pending_events.append(event)

    # ---- step ---------------------------------------------------------------------------------

    def _visibility(self, time_s: float) -> dict[str, tuple[str, Visibility | None]]:
        camera = TrackingCamera(self.tracking, pose=self.camera_pose, seed=None)
        occluders = self._occluders()
        out: dict[str, tuple[str, Visibility | None]] = {}
        for tool, geometry in TOOLS.items():
            held = self.tools.get(tool)
            if held is None:
                out[tool] = ("missing", None)
            elif held.source == "tracker" and time_s - held.time_s > self.stale_after_s:
                out[tool] = ("stale", None)
            else:
                visibility = camera.observe(geometry, held.pose, occluders)
                out[tool] = (visibility.reason, visibility)
        return out

    def reamer_angles_now(self, time_s: float, visibility: dict | None = None) -> dict | None:
        visibility = visibility or self._visibility(time_s)
        if visibility["Reamer"][0] != "tracked" or visibility["Reference"][0] != "tracked":
            return None
        axis = self.tools["Reamer"].pose[:3, :3] @ CUP_AXIS_IN_REAMER
        try:
            return {d: angles_in_frame(axis, self.app, d) for d in DEFINITIONS}
        except ThrsimInputError:
            return None  # pointing medially: no clinical angle

    def step(self, time_s: float, early: Callable[[dict], None] | None = None) -> dict:
        """Advance to ``time_s``: registration, visibility, angles; returns the state for viewers.
        Nothing here is slow, so ``early`` (see :class:`thrsim.app.modes.Trainer`) is never called."""
        if self._probe_tip is not None and self.tools.get("Probe") is not None and self.tools["Probe"].source == "page":
            self._set_page_probe_tremor(time_s)
        visibility = self._visibility(time_s)
        if not self.registration.done:
            self._step_registration(time_s, visibility)
        angles = self.reamer_angles_now(time_s, visibility)
        zone = None if angles is None else safe_zone_status(angles["radiographic"][0], angles["radiographic"][1], self.zone)
        if self._calibration["state"] == "sampling":
            self._step_calibration(time_s)

        self.log.trace_time.append(time_s)
        self.log.trace_angles.extend(
            (math.nan, math.nan, math.nan) if angles is None or zone is None else (*angles["radiographic"], zone.distance_deg)
        )
        self.log.trace_phase.append(1 if self.result is not None else 0)
        self.log.trace_tools.extend(TOOL_STATES.index(visibility[t][0]) for t in TOOLS)
        return self._state(time_s, visibility, angles, zone)

    def _set_page_probe_tremor(self, time_s: float) -> None:
        held, placed = self.tools["Probe"], self._probe_tip
        assert placed is not None  # the step calls this only while the page has placed the tip
        tip = placed + self.rng.normal(0.0, _HAND_TREMOR_SD_M, 3)
        origin = tip - held.pose[:3, :3] @ PROBE.tip
        self.tools["Probe"] = _ToolPose(make_pose(held.pose[:3, :3], origin), "page", held.time_s)

    def _step_registration(self, time_s: float, visibility: dict) -> None:
        probe = self.tools.get("Probe")
        tip = None if probe is None or visibility["Probe"][1] is None else transform_points(probe.pose, PROBE.tip[None])[0]
        seen = {tool: visibility[tool][1] or Visibility(False, visibility[tool][0], 0.0, 0) for tool in ("Probe", "Reference")}
        events = self.registration.update(time_s, tip, seen["Probe"], seen["Reference"])
        for event in events:
            if event.kind == "target" and event.landmark is not None:
                self.log.target_started.setdefault(event.landmark, time_s)
            if event.kind == "acquired" and event.landmark is not None:
                started = self.log.target_started.get(event.landmark, time_s)
                self.log.landmark_time_s[event.landmark] = time_s - started
                # after a retake the next target's clock restarts when the retaken one is done
                following = self.registration.current_target
                if following is not None:
                    self.log.target_started[following] = time_s
            self._event(time_s, event.kind, landmark=event.landmark, detail=event.detail, value=event.error_m)
            if event.kind == "completed":
                self._complete_registration(time_s)

    def _complete_registration(self, time_s: float) -> None:
        self.result = result = self.registration.result(self.model_landmarks, side=self.side)
        self.app = result.app
        self.app_source = "registered"
        self.scene_to_reference = result.fit.pose
        self._event(time_s, "app_built", detail=f"rms {result.rms_residual_m * 1e3:.2f} mm", value=result.rms_residual_m)

    def _step_calibration(self, time_s: float) -> None:
        # One paired observation of the image target per step: the tracker's and the display's.
        target = make_pose(np.eye(3), transform_points(self.model_to_reference, _CALIBRATION_TARGET_MODEL[None])[0])
        viewer_in_reference = self.model_to_reference @ self.viewer_pose
        head = invert(viewer_in_reference) @ target
        head[:3, :3] = _random_rotation_small(self.rng, _HEADSET_NOISE[0] / math.sqrt(3)) @ head[:3, :3]
        head[:3, 3] += self.rng.normal(0.0, _HEADSET_NOISE[1] / math.sqrt(3), 3)
        tracker = invert(self.camera_pose) @ target
        tracker[:3, 3] += self.rng.normal(0.0, _TRACKER_NOISE_M / math.sqrt(3), 3)
        heads, trackers = self._calibration_pairs
        heads.append(head)
        trackers.append(tracker)
        self._calibration["samples"] = len(heads)
        if len(heads) < CALIBRATION_SAMPLES:
            return
        attempt: dict[str, Any] = {"time_s": time_s, "samples": len(heads)}
        try:
            result = calibrate_frames(np.array(heads), np.array(trackers))
        except ThrsimInputError as error:
            self._calibration.update(state="refused", message=str(error), result=None)
            attempt.update(ok=False, message=str(error))
            self._event(time_s, "calibration_refused", detail=str(error))
        else:
            summary = result.as_dict()
            summary.pop("transform")
            self._calibration.update(state="done", message="calibrated", result=summary)
            attempt.update(ok=True, message="calibrated", **summary)
            self._event(
                time_s,
                "calibration_done",
                detail=f"{summary['rotation_residual_rms_deg']:.2f}° / {summary['translation_residual_rms_mm']:.2f} mm",
            )
        self.log.calibrations.append(attempt)

    # ---- output -------------------------------------------------------------------------------

    def defaults(self) -> dict:
        """Where the page's controls start (a new session's): the reamer's aim (radiographic, degrees)."""
        return {"reamer": dict(self.reamer_start)}

    def scene(self) -> dict:
        """What the page needs once per side: landmarks and pelvis geometry (model frame, metres)."""
        other = other_side(self.side)
        return {
            "side": self.side,
            "landmarks": {name: p.tolist() for name, p in self.model_landmarks.items()},
            "pelvis": "/api/pelvis",  # the bone surface (model frame), both hips
            "acetabulum": {self.side: self.acetabulum_model.tolist(), other: acetabulum_centre(other).tolist()},
            "rim_radius_m": ACETABULUM_RIM_RADIUS,
            "calibration_target": _CALIBRATION_TARGET_MODEL.tolist(),
            "volume": self.tracking.model_dump(),
            "zone": self.zone.model_dump(),
            "tool_tips": {name: geometry.tip.tolist() for name, geometry in TOOLS.items()},
            "tool_markers": {name: geometry.markers.tolist() for name, geometry in TOOLS.items()},
            "reamer_head_diameter_m": 0.045,
            "phantom": None if self.phantom is None else self.phantom.summary(),
        }

    def _box_in_scene(self, box: Box) -> dict:
        centre = make_pose(np.eye(3), 0.5 * (box.minimum + box.maximum))
        return {"pose": self._to_scene(centre), "size": (box.maximum - box.minimum).tolist()}

    def _to_scene(self, pose: np.ndarray) -> list[float]:
        return (invert(self.scene_to_reference) @ pose).ravel().tolist()

    def _state(self, time_s: float, visibility: dict, angles: dict | None, zone) -> dict:
        tools = {}
        for tool in TOOLS:
            reason, seen = visibility[tool]
            held = self.tools.get(tool)
            tools[tool] = {
                "pose": None if held is None else self._to_scene(held.pose),
                "tracked": reason == "tracked",
                "reason": reason,
                "angle_deg": None if seen is None else round(seen.angle_deg, 2),
                "source": None if held is None else held.source,
            }
        registration = {
            "total": len(self.targets),
            "acquired": list(self.registration.acquired),
            "current": self.registration.current_target,
            "done": self.result is not None,
            "rms_mm": None if self.result is None else self.result.rms_residual_m * 1e3,
            "retakes": sum(self.log.retakes.values()),
        }
        if angles is None:
            note = (
                "reamer not tracked"
                if visibility["Reamer"][0] != "tracked"
                else "reference array not tracked"
                if visibility["Reference"][0] != "tracked"
                else "reamer points medially"
            )
        else:
            note = "" if self.result is not None else "angles on the model pelvis: register the landmarks to measure them on this patient"
        events, self._pending_events = self._pending_events, []
        return {
            "type": "state",
            "mode": self.mode,
            "time_s": time_s,
            "side": self.side,
            "definition": self.definition,
            "camera": {
                "pose": self._to_scene(self.camera_pose),
                "source": "page" if self.tracker_camera is None else "tracker",
                **self.camera_spherical,
            },
            "occluder": {"present": self.occluder, "boxes": [self._box_in_scene(box) for box in self._occluders()]},
            "tools": tools,
            "registration": registration,
            "angles": None if angles is None else {d: list(a) for d, a in angles.items()},
            "app_source": self.app_source,
            "zone": None if zone is None else zone.as_dict(),
            "note": note,
            "calibration": {k: v for k, v in self._calibration.items()} | {"needed": CALIBRATION_SAMPLES},
            "headset": self._headset_state(),
            "confirmed": self.log.confirmations[-1] if self.log.confirmations else None,
            "force_n": self.force_n,
            "events": events,
        }

    def settings(self) -> dict:
        return {
            "side": self.side,
            "seed": self.seed,
            "zone": self.zone.model_dump(),
            "tracking": self.tracking.model_dump(),
            "stale_after_s": self.stale_after_s,
        }

    def record(self) -> NavigationRecord:
        """Everything the report needs from this session so far."""
        names = list(self.targets)
        acquired = np.array([self.registration.acquired.get(n, np.full(3, np.nan)) for n in names])
        residual = np.full(len(names), np.nan)
        if self.result is not None:
            order = list(self.result.acquired)
            residual = np.array([self.result.fit.residuals[order.index(n)] for n in names])
        return NavigationRecord(
            side=self.side,
            tools=list(TOOLS),
            tool_states=list(TOOL_STATES),
            zone=self.zone.model_dump(),
            time=np.array(self.log.trace_time, dtype=float),
            angles=np.array(self.log.trace_angles, dtype=float).reshape(-1, 3),
            phase=np.array(self.log.trace_phase, dtype=np.int8),
            tool_codes=np.array(self.log.trace_tools, dtype=np.uint8).reshape(-1, len(TOOLS)),
            events=list(self.log.events),
            names=names,
            targets=np.array([self.targets[n] for n in names]),
            acquired=acquired,
            residual_m=residual,
            landmark_time_s=np.array([self.log.landmark_time_s.get(n, np.nan) for n in names]),
            retakes=np.array([self.log.retakes.get(n, 0) for n in names], dtype=int),
            completed=self.result is not None,
            rms_m=math.nan if self.result is None else self.result.rms_residual_m,
            calibrations=list(self.log.calibrations),
            confirmations=list(self.log.confirmations),
        )

    def write(self, group) -> None:
        """Fill this mode's group of the session file."""
        write_navigation(group, self.record(), self.settings())
