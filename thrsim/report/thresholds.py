"""Competency thresholds of the reaming report, in a file an instructor may edit.

The defaults ship with the package (``thrsim/report/thresholds.yaml``, each with its published
source or marked as thrsim's own); ``thrsim serve --thresholds FILE`` and ``thrsim report
--thresholds FILE`` score against an instructor's file instead (JSON, or YAML for a ``.yaml`` or
``.yml`` name), whose entries replace the defaults' one by one. Each entry has a ``full`` value
that earns a criterion's points and a ``partial`` one that earns half; whether a value must stay
at most or at least that is the criterion's (:mod:`thrsim.report.reaming`).
"""

from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator

from thrsim.session.plan import read_small_file

DEFAULTS = Path(__file__).with_name("thresholds.yaml")


class _Entry(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    full: float = Field(ge=0)
    partial: float = Field(ge=0)
    source: str = Field("set by the instructor", max_length=1000)


class AtMost(_Entry):
    """A value that must stay at most ``full`` for the points, at most ``partial`` for half."""

    @model_validator(mode="after")
    def _ordered(self) -> AtMost:
        if self.partial < self.full:
            raise ValueError("partial must be at least full (more is worse)")
        return self


class AtLeast(_Entry):
    """A value that must reach ``full`` for the points, ``partial`` for half."""

    @model_validator(mode="after")
    def _ordered(self) -> AtLeast:
        if self.partial > self.full:
            raise ValueError("partial must be at most full (more is better)")
        return self


class Fraction(AtLeast):
    full: float = Field(ge=0, le=1)
    partial: float = Field(ge=0, le=1)


class Thresholds(BaseModel):
    """Every threshold the reaming criteria score against (see the shipped file for each one's meaning)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    orientation_error_deg: AtMost
    within_10deg_fraction: Fraction
    cavity_diameter_error_mm: AtMost
    centre_error_mm: AtMost
    reamer_step_mm: AtMost
    final_reamer_under_cup_mm: AtMost
    safe_zone_fraction: Fraction
    push_in_range_fraction: Fraction
    over_reaming_fraction: AtMost
    prepared_fraction: Fraction
    corrections: AtMost


#: an instructor's file: any of the entries, each one whole
_InstructorFile = create_model(  # type: ignore[call-overload]  # fields built from Thresholds' own, made optional
    "_InstructorFile",
    __config__=ConfigDict(extra="forbid", frozen=True),
    **{name: (field.annotation | None, None) for name, field in Thresholds.model_fields.items()},  # type: ignore[operator]
)


def default_thresholds() -> Thresholds:
    """The shipped defaults."""
    return Thresholds.model_validate(yaml.safe_load(DEFAULTS.read_text(encoding="utf-8")))


def load_thresholds(path: str | Path | None) -> Thresholds:
    """The defaults with an instructor's file's entries in their place (None: the defaults alone);
    one ThrsimInputError line when the file cannot be read or holds a bad entry."""
    defaults = default_thresholds()
    if path is None:
        return defaults
    given = read_small_file(Path(path), "thresholds file", _InstructorFile)
    return defaults.model_copy(update={name: entry for name, entry in given if entry is not None})
