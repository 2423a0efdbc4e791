"""Navigation trainer core: APP frame and cup angles, safe zone, tracking model, landmark
registration and frame calibration. Pure numerics; the OpenIGTLink edge lives in thrsim.io."""

from thrsim.nav.anatomy import AppFrame, angles_in_frame, app_frame, convert_angles, cup_angles, local_axis_from_angles
from thrsim.nav.calibration import CalibrationRefused, FrameCalibration, calibrate_frames
from thrsim.nav.pelvis import synthetic_pelvis_landmarks
from thrsim.nav.registration import LandmarkRegistration, RegistrationEvent, RegistrationResult
from thrsim.nav.safe_zone import SafeZoneStatus, safe_zone_status
from thrsim.nav.session import NavigationSession
from thrsim.nav.tracking import PROBE, REAMER, REFERENCE_FRAME, Box, Sphere, ToolGeometry, TrackingCamera, Visibility, look_at

__all__ = [
    "PROBE",
    "REAMER",
    "REFERENCE_FRAME",
    "AppFrame",
    "Box",
    "CalibrationRefused",
    "FrameCalibration",
    "LandmarkRegistration",
    "NavigationSession",
    "RegistrationEvent",
    "RegistrationResult",
    "SafeZoneStatus",
    "Sphere",
    "ToolGeometry",
    "TrackingCamera",
    "Visibility",
    "angles_in_frame",
    "app_frame",
    "calibrate_frames",
    "convert_angles",
    "cup_angles",
    "local_axis_from_angles",
    "look_at",
    "safe_zone_status",
    "synthetic_pelvis_landmarks",
]
