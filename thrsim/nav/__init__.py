"""Navigation trainer core: APP frame and cup angles, the bone frame's place in it, safe zone,
tracking model, landmark registration and frame calibration. Pure numerics; the OpenIGTLink edge lives in thrsim.io."""

import importlib

# Names are imported on first use (PEP 562): `thrsim nav ...` and the server then load only
# what they need, and scipy.spatial stays out of every other command's start-up.
_SOURCES = {
    "AppFrame": "thrsim.nav.anatomy",
    "Box": "thrsim.nav.tracking",
    "CalibrationRefused": "thrsim.nav.calibration",
    "FrameCalibration": "thrsim.nav.calibration",
    "LandmarkRegistration": "thrsim.nav.registration",
    "TrackerState": "thrsim.nav.tracker_state",
    "PROBE": "thrsim.nav.tracking",
    "REAMER": "thrsim.nav.tracking",
    "REFERENCE_FRAME": "thrsim.nav.tracking",
    "RegistrationEvent": "thrsim.nav.registration",
    "RegistrationResult": "thrsim.nav.registration",
    "SafeZoneStatus": "thrsim.nav.safe_zone",
    "Sphere": "thrsim.nav.tracking",
    "ToolGeometry": "thrsim.nav.tracking",
    "TrackingCamera": "thrsim.nav.tracking",
    "Visibility": "thrsim.nav.tracking",
    "angles_in_frame": "thrsim.nav.anatomy",
    "app_frame": "thrsim.nav.anatomy",
    "bone_angles_from_cup": "thrsim.nav.bone_frame",
    "calibrate_frames": "thrsim.nav.calibration",
    "convert_angles": "thrsim.nav.anatomy",
    "cup_angles": "thrsim.nav.anatomy",
    "cup_angles_from_bone": "thrsim.nav.bone_frame",
    "local_axis_from_angles": "thrsim.nav.anatomy",
    "look_at": "thrsim.nav.tracking",
    "safe_zone_status": "thrsim.nav.safe_zone",
    "synthetic_pelvis_landmarks": "thrsim.nav.pelvis",
}


def __getattr__(name: str):
    if name in _SOURCES:
        return getattr(importlib.import_module(_SOURCES[name]), name)
    raise AttributeError(f"module 'thrsim.nav' has no attribute {name!r}")


__all__ = [
    "PROBE",
    "REAMER",
    "REFERENCE_FRAME",
    "AppFrame",
    "Box",
    "CalibrationRefused",
    "FrameCalibration",
    "LandmarkRegistration",
    "TrackerState",
    "RegistrationEvent",
    "RegistrationResult",
    "SafeZoneStatus",
    "Sphere",
    "ToolGeometry",
    "TrackingCamera",
    "Visibility",
    "angles_in_frame",
    "app_frame",
    "bone_angles_from_cup",
    "calibrate_frames",
    "convert_angles",
    "cup_angles",
    "cup_angles_from_bone",
    "local_axis_from_angles",
    "look_at",
    "safe_zone_status",
    "synthetic_pelvis_landmarks",
]
