"""A physical pelvis phantom (a lab's 3-D print) and where a headset shows the virtual bone on it.

A phantom file names bony landmarks in the phantom's own frame, the frame of the marker array fixed
to it (what a tracker streams as ``ReferenceToTracker``), in millimetres, and the headset's
calibration target: where a controller sits, seated in a cradle on the phantom's base, while the
headset and the tracker both observe it (the display calibration of the thesis's §3.3). The model's
landmarks fitted onto the phantom's give T_reference←model; the calibration (the robust average of
:func:`thrsim.nav.calibration.calibrate_frames`) gives T_headset←tracker; their product with the
tracker's T_tracker←reference places the bone in the headset's space. Pure numerics.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from thrsim.errors import ThrsimInputError
from thrsim.nav.pelvis import synthetic_pelvis_landmarks
from thrsim.nav.rigid import RigidFit, check_pose, make_pose, rigid_fit

#: the shipped phantom: the simulated pelvis with its marker array on the right iliac crest
SIMULATED_PHANTOM = Path(__file__).with_name("simulated_pelvis_phantom.json")
#: a phantom whose landmarks fit the model's worse than this (RMS) is not this pelvis (mm)
MAX_PHANTOM_FIT_MM = 5.0
#: landmarks a phantom is fitted by: the model's that lie where they lie whichever hip is operated
#: (the acetabular rim points are the operated hip's own)
FIT_LANDMARKS: tuple[str, ...] = tuple(
    name for name, point in synthetic_pelvis_landmarks("right").items() if np.allclose(point, synthetic_pelvis_landmarks("left")[name])
)

_Point = Annotated[list[float], Field(min_length=3, max_length=3)]


class PhantomFile(BaseModel):
    """A phantom definition file (JSON): landmarks and the calibration target in the phantom's frame (mm)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    name: str = Field(..., min_length=1, max_length=80, description="what the phantom is (shown on the page)")
    landmarks_mm: dict[str, _Point] = Field(..., min_length=3, description="bony landmarks by the model's names (FIT_LANDMARKS)")
    calibration_target_mm: _Point = Field(..., description="where the controller's grip sits in its cradle")
    calibration_target_rotation: list[_Point] = Field(
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        min_length=3,
        max_length=3,
        description="the cradle's axes in the phantom's frame (rows of a rotation matrix; the grip's axes when seated)",
    )


@dataclass(frozen=True)
class Phantom:
    """A loaded phantom: its fit to the model (T_reference←model) and its calibration target (T_reference←target)."""

    name: str
    fit: RigidFit  # model landmarks → phantom landmarks (metres)
    target: np.ndarray  # T_reference←target

    @property
    def reference_from_model(self) -> np.ndarray:
        return self.fit.pose

    def summary(self) -> dict:
        return {"name": self.name, "fit_rms_mm": self.fit.rms * 1e3, "landmarks": len(self.fit.residuals)}


def phantom_from_file(definition: PhantomFile) -> Phantom:
    """The model's landmarks fitted onto the file's; refused when too few are named or they do not fit."""
    names = [name for name in FIT_LANDMARKS if name in definition.landmarks_mm]
    if len(names) < 3:
        raise ThrsimInputError(f"a phantom needs at least 3 of the landmarks {', '.join(FIT_LANDMARKS)}; it names {len(names)}")
    model = synthetic_pelvis_landmarks("right")
    fit = rigid_fit(np.array([model[n] for n in names]), np.array([definition.landmarks_mm[n] for n in names]) * 1e-3)
    if fit.rms * 1e3 > MAX_PHANTOM_FIT_MM:
        raise ThrsimInputError(
            f"the phantom's landmarks fit the simulated pelvis to {fit.rms * 1e3:.1f} mm RMS (at most {MAX_PHANTOM_FIT_MM:g} mm): not this pelvis"
        )
    rotation = np.array(definition.calibration_target_rotation)
    target = check_pose(make_pose(rotation, np.array(definition.calibration_target_mm) * 1e-3), "phantom calibration target")
    return Phantom(name=definition.name, fit=fit, target=target)


def read_phantom_file(path: str | Path) -> PhantomFile:
    """A phantom definition file, checked to fit the simulated pelvis; one ThrsimInputError line when it cannot be read, parsed or fitted."""
    from thrsim.session.plan import read_small_file

    definition: PhantomFile = read_small_file(Path(path), "phantom file", PhantomFile)  # type: ignore[assignment]
    try:
        phantom_from_file(definition)
    except ThrsimInputError as error:
        raise ThrsimInputError(f"{path}: {error}") from None
    return definition


def headset_from_model(
    headset_from_tracker: np.ndarray, tracker_from_reference: np.ndarray, reference_from_model: np.ndarray
) -> np.ndarray:
    """T_headset←model: where the headset draws the model's frame so the bone lies on the phantom."""
    return check_pose(headset_from_tracker, "headset calibration") @ tracker_from_reference @ reference_from_model
