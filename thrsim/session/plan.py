"""The reaming plan: the templated cup and where it is to sit, fixed before reaming starts.

The trainee sets it on the reaming page before the first frame is reamed, or an instructor gives
it in a case file (``thrsim serve --plan FILE``: JSON, or YAML for a ``.yaml``/``.yml`` name),
which the trainee cannot change. The report measures the session against it
(:mod:`thrsim.report.reaming_metrics`). Angles are the radiographic cup angles the page shows
(Murray), in the patient's anterior pelvic plane; the centre is the planned centre of rotation as
a shift from the native socket's centre, medially and superiorly, in millimetres. The patient's
socket (its native size and cancellous bone) is the case's: where the served model reams the whole
socket, the trainer meshes that socket (:func:`thrsim.app.reaming.socket_in_patch`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from thrsim.config import CANCELLOUS_PRESETS, SafeZone, SocketConfig
from thrsim.errors import ThrsimInputError
from thrsim.nav.anatomy import local_axis_from_angles
from thrsim.nav.bone_frame import patch_in_app

#: the reamer and cup sizes the trainer offers (mm, whole millimetres: the diameter the teeth cut)
REAMER_SIZES_MM = tuple(range(40, 65))
#: a session's first reamer is this much under the templated cup: reaming starts a few millimetres
#: under it and steps up
FIRST_REAMER_UNDER_CUP_MM = 4
#: a case file is a few lines; anything far larger is not one
MAX_CASE_FILE_BYTES = 64 * 1024


class Plan(BaseModel):
    """A templated cup: its size, its centre against the native one, its orientation (radiographic)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    cup_diameter_mm: float = Field(48.0, ge=REAMER_SIZES_MM[0], le=REAMER_SIZES_MM[-1], description="templated cup's outer diameter")
    medialisation_mm: float = Field(0.0, ge=-10.0, le=10.0, description="planned centre of rotation, medial of the native centre")
    superior_shift_mm: float = Field(0.0, ge=-10.0, le=10.0, description="planned centre of rotation, superior of the native centre")
    inclination_deg: float = Field(SafeZone().inclination_deg, ge=0.0, le=90.0, description="radiographic inclination of the cup")
    anteversion_deg: float = Field(SafeZone().anteversion_deg, ge=-90.0, le=90.0, description="radiographic anteversion of the cup")
    native_socket_mm: float = Field(
        SocketConfig().socket_diameter_mm, description="the patient's native socket diameter (a whole-socket model reams this socket)"
    )
    cancellous: str = Field("normal", description="the patient's cancellous bone, a preset: normal or osteoporotic")

    @field_validator("native_socket_mm")
    @classmethod
    def _a_socket_size(cls, value: float) -> float:
        try:
            SocketConfig(socket_diameter_mm=value)  # the socket's own bounds
        except ValidationError as error:
            raise ValueError(error.errors()[0]["msg"]) from None
        return value

    @field_validator("cancellous")
    @classmethod
    def _known_cancellous(cls, value: str) -> str:
        if value not in CANCELLOUS_PRESETS:
            raise ValueError(f"unknown cancellous bone {value!r}: known {', '.join(sorted(CANCELLOUS_PRESETS))}")
        return value

    def as_metric(self, source: str) -> dict:
        """The plan as the report's ``plan`` metric: cup diameter, centre, inclination, anteversion and who set it."""
        return {
            "cup_diameter_mm": self.cup_diameter_mm,
            "centre": {"medialisation_mm": self.medialisation_mm, "superior_shift_mm": self.superior_shift_mm},
            "inclination_deg": self.inclination_deg,
            "anteversion_deg": self.anteversion_deg,
            "source": source,
        }

    def cup_in_patch(self, zone: SafeZone) -> tuple[np.ndarray, np.ndarray]:
        """The planned cup in the bone patch's frame (placed at ``zone``'s centre): its centre (m), the
        native centre (the frame's origin) shifted medially and superiorly, and its axis (unit, out of
        the socket). The page draws it and the report measures the cavity against it."""
        to_patch = patch_in_app(zone).T  # APP components (lateral, anterior, inferior) to the patch's
        shift_app = np.array([-self.medialisation_mm, 0.0, -self.superior_shift_mm]) * 1e-3
        return to_patch @ shift_app, to_patch @ local_axis_from_angles(self.inclination_deg, self.anteversion_deg)

    def first_reamer_mm(self) -> int:
        """The reamer a session starts with: the offered size a few millimetres under the cup."""
        wanted = round(self.cup_diameter_mm) - FIRST_REAMER_UNDER_CUP_MM
        return min(max(wanted, REAMER_SIZES_MM[0]), REAMER_SIZES_MM[-1])


def _parse(path: Path, text: str) -> object:
    if path.suffix.lower() in (".yaml", ".yml"):
        import yaml

        try:
            return yaml.safe_load(text)
        except yaml.YAMLError as error:
            raise ThrsimInputError(f"{path}: not YAML ({str(error).splitlines()[0]})") from None
    try:
        return json.loads(text)
    except ValueError as error:
        raise ThrsimInputError(f"{path}: not JSON ({error})") from None


def read_small_file(path: Path, what: str, model: type[BaseModel]) -> BaseModel:
    """An instructor's small JSON or YAML file validated by ``model``; one ThrsimInputError line when it cannot be."""
    try:
        if path.stat().st_size > MAX_CASE_FILE_BYTES:
            raise ThrsimInputError(f"{path}: {path.stat().st_size} bytes is not a {what} (at most {MAX_CASE_FILE_BYTES})")
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise ThrsimInputError(f"cannot read the {what} {path}: {getattr(error, 'strerror', None) or error}") from None
    data = _parse(path, text)
    if not isinstance(data, dict):
        raise ThrsimInputError(f"{path}: a {what} is one object of named values")
    try:
        return model.model_validate(data)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(p) for p in first.get("loc", ())) or "file"
        where = where if where.isprintable() and len(where) <= 64 else repr(where)[:64] + "…"
        raise ThrsimInputError(f"{path}: {where}: {first.get('msg', 'invalid')}") from None


def load_plan(path: str | Path) -> Plan:
    """An instructor's case file: the plan's values by name (any left out take the defaults)."""
    return read_small_file(Path(path), "case file", Plan)  # type: ignore[return-value]
