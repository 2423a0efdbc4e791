"""The reamer's aim on the command line: the bone frame's γ/θ or the clinical cup angles, one pair of them.

``thrsim ream`` and ``thrsim fem`` take either ``--inclination/--anteversion`` (γ, θ: the reamer axis
relative to the socket axis, as the case files store it) or ``--cup-inclination/--cup-anteversion``
(Murray's radiographic angles in the anterior pelvic plane, as the trainer shows them); the
conversion is the trainer's (:mod:`thrsim.nav.bone_frame`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import typer

from thrsim.errors import ThrsimInputError
from thrsim.nav.bone_frame import bone_angles_from_cup, cup_angles_from_bone

_RELATION = "the bone frame's γ/θ and the cup angles are one aim, converted as the trainer places the bone (γ 0 = cup 40°/15°)"
GAMMA_HELP = "reamer inclination γ in degrees [0, 90]: the reamer axis's tilt from the socket axis, in the bone frame"
THETA_HELP = "reamer anteversion θ in degrees [0, 360]: the direction of that tilt about the socket axis, in the bone frame"
CUP_INCLINATION = typer.Option(
    None,
    "--cup-inclination",
    help=f"clinical cup inclination in degrees [0, 90] (radiographic, anterior pelvic plane, as the trainer shows it), with --cup-anteversion, instead of --inclination/--anteversion; {_RELATION}",
    metavar="DEG",
)
CUP_ANTEVERSION = typer.Option(
    None,
    "--cup-anteversion",
    help="clinical cup anteversion in degrees [-90, 90] (radiographic, anterior pelvic plane; retroversion negative), with --cup-inclination",
    metavar="DEG",
)


@dataclass(frozen=True)
class Aim:
    """One reamer aim in both frames (degrees); the cup angles are None where the cup axis points into the pelvis."""

    inclination_deg: float
    anteversion_deg: float
    cup_inclination_deg: float | None
    cup_anteversion_deg: float | None

    def as_dict(self) -> dict:
        return asdict(self)


def _check(value: float, low: float, high: float, flag: str) -> None:
    if not (math.isfinite(value) and low <= value <= high):
        raise ThrsimInputError(f"{flag} must lie in [{low:g}, {high:g}] degrees, got {value:g}")


def resolve_aim(
    inclination: float | None,
    anteversion: float | None,
    cup_inclination: float | None,
    cup_anteversion: float | None,
    default: tuple[float, float] | None = None,
) -> Aim:
    """The aim from the flags given: one pair only; a bone-frame flag left out takes ``default`` (none: both needed)."""
    bone_given = inclination is not None or anteversion is not None
    cup_given = cup_inclination is not None or cup_anteversion is not None
    if bone_given and cup_given:
        raise ThrsimInputError(
            "give the bone frame's --inclination/--anteversion or the clinical --cup-inclination/--cup-anteversion, not both"
        )
    if cup_given:
        if cup_inclination is None or cup_anteversion is None:
            raise ThrsimInputError("--cup-inclination and --cup-anteversion go together: give both")
        _check(cup_inclination, 0.0, 90.0, "--cup-inclination")
        _check(cup_anteversion, -90.0, 90.0, "--cup-anteversion")
        gamma, theta = bone_angles_from_cup(cup_inclination, cup_anteversion)
        if gamma > 90.0:
            raise ThrsimInputError(
                f"cup {cup_inclination:g}°/{cup_anteversion:g}° is γ {gamma:.1f}° from the socket axis: beyond 90° the reamer points out of the bone"
            )
        return Aim(gamma, theta, cup_inclination, cup_anteversion)
    if inclination is None or anteversion is None:
        if default is None:
            raise ThrsimInputError(
                "give the aim: --inclination and --anteversion (bone frame), or --cup-inclination and --cup-anteversion (clinical)"
            )
        gamma, theta = default[0] if inclination is None else inclination, default[1] if anteversion is None else anteversion
    else:
        gamma, theta = inclination, anteversion
    _check(gamma, 0.0, 90.0, "--inclination")
    _check(theta, 0.0, 360.0, "--anteversion")
    cup = cup_angles_from_bone(gamma, theta)
    return Aim(gamma, theta, *(cup if cup is not None else (None, None)))
