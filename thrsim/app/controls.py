"""The page's control messages, validated before anything acts on them.

Each WebSocket message is one JSON object whose ``type`` picks the model; a field out of its
range or of another JSON type (``"200"`` or ``true`` is not a number), an unknown type or a message
that is not JSON (nested too deeply, an integer of thousands of digits) is refused with a one-line
reason and the session goes on. Degrees and millimetres here (the user-facing edge); the trainer converts.
"""

from __future__ import annotations

import json
import reprlib
from typing import Annotated, Any, Literal, Union, get_args

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, model_validator

from thrsim.config import Side
from thrsim.errors import ThrsimInputError
from thrsim.session.plan import REAMER_SIZES_MM

MAX_MESSAGE_BYTES = 16 * 1024
#: a placed probe tip is within this of the pelvis model's origin (millimetres)
MAX_TIP_MM = 1000.0
#: a trainee's name or ID: it is shown on pages and names the trainee's page (/trainee/<id>)
TRAINEE_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9 ._-]*$"


class _Control(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)
    type: str  # each control's own Literal: the discriminator


class CameraControl(_Control):
    """Where the IR camera stands, in spherical coordinates around the operated acetabulum."""

    type: Literal["camera"]
    azimuth_deg: float = Field(..., ge=-180, le=180)
    elevation_deg: float = Field(..., ge=-89, le=89)
    distance_mm: float = Field(..., ge=300, le=3500)


class ReamerControl(_Control):
    """Steer the reamer (no tracker): radiographic angles in the patient's true APP."""

    type: Literal["reamer"]
    inclination_deg: float = Field(..., ge=0, le=90)
    anteversion_deg: float = Field(..., ge=-90, le=90)


class ProbeControl(_Control):
    """The probe without a tracker: ``place`` its tip where the trainee moved it (``tip_mm``, the
    page's scene frame, millimetres), ``lift`` it, or ``touch`` a landmark (the current target when
    none is named; a scripted hand that lands within the acquisition tolerance, for tests and demos)."""

    type: Literal["probe"]
    action: Literal["touch", "lift", "place"]
    landmark: str | None = Field(None, max_length=64)
    tip_mm: list[float] | None = Field(None, min_length=3, max_length=3)

    @model_validator(mode="after")
    def _tip_with_place(self) -> ProbeControl:
        if (self.action == "place") != (self.tip_mm is not None):
            raise ValueError("tip_mm is given with action place, and only then")
        if self.tip_mm is not None and max(map(abs, self.tip_mm)) > MAX_TIP_MM:
            raise ValueError(f"tip_mm beyond {MAX_TIP_MM:g} mm of the pelvis")
        return self


class RegistrationControl(_Control):
    type: Literal["registration"]
    action: Literal["retake", "restart"]


class DefinitionControl(_Control):
    type: Literal["definition"]
    value: Literal["radiographic", "operative", "anatomic"]


class SideControl(_Control):
    type: Literal["side"]
    value: Side


class OccluderControl(_Control):
    """A surgeon's arm between the camera and the pelvis (to practise occlusions)."""

    type: Literal["occluder"]
    present: bool


class ViewerControl(_Control):
    """The display's own pose in the scene (model frame, metres, 16 numbers row-major)."""

    type: Literal["viewer"]
    pose: list[float] = Field(..., min_length=16, max_length=16)


class CalibrationControl(_Control):
    type: Literal["calibration"]
    action: Literal["start"]


class HeadsetControl(_Control):
    """A headset's calibration against the tracker: ``start``, one ``target`` per headset frame (``pose``:
    the controller seated on the calibration target, T_headset←target, metres, 16 numbers row-major), ``clear``."""

    type: Literal["headset"]
    action: Literal["start", "target", "clear"]
    pose: list[float] | None = Field(None, min_length=16, max_length=16)

    @model_validator(mode="after")
    def _pose_with_target(self) -> HeadsetControl:
        if (self.action == "target") != (self.pose is not None):
            raise ValueError("pose is given with action target, and only then")
        if self.pose is not None and max(map(abs, self.pose)) > MAX_TIP_MM:
            raise ValueError(f"pose beyond {MAX_TIP_MM:g} m of the headset's origin")
        return self


class ReamerAxisControl(_Control):
    """Aim the reamer (no tracker) along its shaft: ``axis``, the scene frame's direction out of the socket
    toward the hand (a headset's controller held as the reamer); the page's angle limits apply."""

    type: Literal["reamer_axis"]
    axis: list[float] = Field(..., min_length=3, max_length=3)

    @model_validator(mode="after")
    def _direction(self) -> ReamerAxisControl:
        if not 1e-6 <= sum(x * x for x in self.axis) <= 1e6:
            raise ValueError("axis must be a direction of length between 1e-3 and 1e3")
        return self


class ConfirmControl(_Control):
    """Lock the current reamer orientation as the planned cup orientation."""

    type: Literal["confirm_cup"]


class EndSessionControl(_Control):
    type: Literal["end_session"]


class TraineeControl(_Control):
    """Who trains in this session (a name or an ID), recorded in its file; 1–40 letters, digits,
    spaces and ``. _ -``, starting with a letter or digit (it names the trainee's page)."""

    type: Literal["trainee"]
    id: str = Field(..., min_length=1, max_length=40, pattern=TRAINEE_PATTERN)


#: the controls the live session acts on itself, never its trainer (a replay skips them)
SESSION_CONTROLS: tuple[str, ...] = ("end_session", "trainee")


#: the largest push the reaming mode takes (the model card says which push it learned)
MAX_FORCE_N = 400.0


class RunControl(_Control):
    """Reaming: start or pause the simulation, restore the intact bone, or undo the last second."""

    type: Literal["run"]
    action: Literal["start", "pause", "reset", "undo"]


class PageControl(_Control):
    """Reaming: the trainee's page shown or hidden (the Page Visibility API); hidden holds reaming."""

    type: Literal["page"]
    visible: bool


class ForceControl(_Control):
    """Reaming: the push along the reamer axis when no force sensor streams."""

    type: Literal["force"]
    newton: float = Field(..., ge=0, le=MAX_FORCE_N)


class PlanControl(_Control):
    """Reaming: the trainee's plan, before reaming starts (:class:`~thrsim.session.plan.Plan`: cup size, centre, angles)."""

    type: Literal["plan"]
    cup_diameter_mm: float = Field(..., ge=REAMER_SIZES_MM[0], le=REAMER_SIZES_MM[-1])
    medialisation_mm: float = Field(..., ge=-10, le=10)
    superior_shift_mm: float = Field(..., ge=-10, le=10)
    inclination_deg: float = Field(..., ge=0, le=90)
    anteversion_deg: float = Field(..., ge=-90, le=90)


class ReamerSizeControl(_Control):
    """Reaming: swap to the reamer of this size (mm; the sizes the trainer offers)."""

    type: Literal["reamer_size"]
    size_mm: int = Field(..., ge=REAMER_SIZES_MM[0], le=REAMER_SIZES_MM[-1])


_NAVIGATION = (
    CameraControl,
    ReamerControl,
    ProbeControl,
    RegistrationControl,
    DefinitionControl,
    SideControl,
    OccluderControl,
    ViewerControl,
    CalibrationControl,
    HeadsetControl,
    ReamerAxisControl,
    ConfirmControl,
    EndSessionControl,
    TraineeControl,
)
# the reaming mode keeps the navigation trainer's controls (it composes that trainer) and adds its own
_REAMING = (*_NAVIGATION, RunControl, ForceControl, PageControl, PlanControl, ReamerSizeControl)


class _Parser:
    """Validates one mode's control messages: one JSON object whose ``type`` picks the model."""

    def __init__(self, models: tuple[type[_Control], ...]):
        # a union built at run time is a typing form that pydantic's stubs type differently across versions: held as Any
        union: Any = Annotated[Union[models], Field(discriminator="type")]  # noqa: UP007 (a tuple of models)
        self.adapter: TypeAdapter = TypeAdapter(union)
        self.types: tuple[str, ...] = tuple(sorted(get_args(m.model_fields["type"].annotation)[0] for m in models))

    def __call__(self, text: str | bytes | dict) -> _Control:
        if isinstance(text, (str, bytes)):
            if len(text) > MAX_MESSAGE_BYTES:
                raise ThrsimInputError(f"control message of {len(text)} bytes exceeds {MAX_MESSAGE_BYTES}")
            try:
                text = json.loads(text)
            except (json.JSONDecodeError, UnicodeDecodeError):
                raise ThrsimInputError("control message is not JSON") from None
            except ValueError:  # Python's cap on the digits of an integer
                raise ThrsimInputError("control message holds a number of too many digits") from None
            except RecursionError:
                raise ThrsimInputError("control message nests too deeply") from None
        if not isinstance(text, dict):
            raise ThrsimInputError("control message must be a JSON object with a 'type'")
        if text.get("type") not in self.types:
            raise ThrsimInputError(f"unknown control type {_shown(text.get('type'))}; known: {', '.join(self.types)}")
        try:
            return self.adapter.validate_python(text)
        except ValidationError as error:
            first = error.errors()[0]
            where = ".".join(str(p) for p in first.get("loc", ())[1:]) or "message"
            where = where if where.isprintable() and len(where) <= 64 else _shown(where)
            raise ThrsimInputError(f"{text['type']} control refused: {where}: {first.get('msg', 'invalid')}") from None


_SHOWN = reprlib.Repr()  # attributes, not keywords: Python 3.11
_SHOWN.maxlevel, _SHOWN.maxstring, _SHOWN.maxlong, _SHOWN.maxother = 2, 40, 40, 40


def _shown(value: object) -> str:
    """A refused value or field name as a refusal quotes it: a short repr, so a peer's value can
    neither flood the log nor break its line."""
    text = _SHOWN.repr(value)
    return text if len(text) <= 80 else text[:79] + "…"


_NAVIGATION_PARSER = _Parser(_NAVIGATION)
_REAMING_PARSER = _Parser(_REAMING)
CONTROL_TYPES: tuple[str, ...] = _NAVIGATION_PARSER.types
REAMING_CONTROL_TYPES: tuple[str, ...] = _REAMING_PARSER.types


def parse_control(text: str | bytes | dict) -> _Control:
    """One navigation control from a WebSocket text frame (or a decoded object); ThrsimInputError says why not."""
    return _NAVIGATION_PARSER(text)


def parse_reaming_control(text: str | bytes | dict) -> _Control:
    """One reaming-mode control (the navigation controls plus run and force)."""
    return _REAMING_PARSER(text)
