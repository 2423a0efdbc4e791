"""``thrsim nav``: navigation geometry for scripting — cup angles from landmarks, conversions."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from thrsim.cli.output import command_group, print_json, print_table
from thrsim.config import SafeZone
from thrsim.errors import ThrsimInputError
from thrsim.nav.anatomy import APP_LANDMARKS, DEFINITIONS, angles_in_frame, app_frame, convert_angles
from thrsim.nav.safe_zone import safe_zone_status

app = command_group("Navigation geometry: cup angles in the anterior pelvic plane, definition conversions.")

_VECTOR_HELP = "three numbers 'x,y,z' (write --flag=-1,0,0 when the first is negative)"


def _vector(text: str, flag: str) -> list[float]:
    try:
        values = [float(part) for part in text.replace(" ", "").split(",")]
    except ValueError:
        raise ThrsimInputError(f"{flag} must be three numbers 'x,y,z', got {text!r}") from None
    if len(values) != 3:
        raise ThrsimInputError(f"{flag} must be three numbers 'x,y,z', got {len(values)} in {text!r}")
    return values


def _landmarks(from_file: Path | None, flags: dict[str, str | None]) -> dict[str, list[float]]:
    landmarks: dict[str, list[float]] = {}
    if from_file is not None:
        try:
            loaded = json.loads(from_file.read_text())
        except (OSError, json.JSONDecodeError) as error:
            raise ThrsimInputError(f"{from_file}: cannot read landmarks JSON: {error}") from None
        if not isinstance(loaded, dict):
            raise ThrsimInputError(f"{from_file}: landmarks JSON must be an object of name: [x, y, z]")
        landmarks.update(loaded)
    for name, text in flags.items():
        if text is not None:
            landmarks[name] = _vector(text, "--" + name.replace("_", "-"))
    missing = [name for name in APP_LANDMARKS if name not in landmarks]
    if missing:
        raise ThrsimInputError(f"missing landmarks: {', '.join(missing)} (give --{missing[0].replace('_', '-')} or --landmarks FILE)")
    return landmarks


@app.command("angles")
def angles(
    axis: str = typer.Option(..., "--axis", help=f"unit cup axis pointing out of the acetabulum: {_VECTOR_HELP}"),
    asis_right: str | None = typer.Option(None, "--asis-right", help="right ASIS (any length unit, same for all)"),
    asis_left: str | None = typer.Option(None, "--asis-left", help="left ASIS"),
    pubic_right: str | None = typer.Option(None, "--pubic-right", help="right pubic tubercle"),
    pubic_left: str | None = typer.Option(None, "--pubic-left", help="left pubic tubercle"),
    landmarks_file: Path | None = typer.Option(
        None, "--landmarks", help="JSON object of landmark name: [x, y, z]; flags override it", metavar="FILE"
    ),
    side: str = typer.Option("right", "--side", help="operated hip: right or left"),
    definition: str = typer.Option("radiographic", "--definition", help="radiographic, operative or anatomic (Murray 1993)"),
    plane: str = typer.Option("standard", "--plane", help="standard (both pubic tubercles) or three_point (ipsilateral one)"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Cup inclination and anteversion from APP landmarks and a cup axis, with the safe-zone verdict."""
    landmarks = _landmarks(
        landmarks_file, {"asis_right": asis_right, "asis_left": asis_left, "pubic_right": pubic_right, "pubic_left": pubic_left}
    )
    if definition not in DEFINITIONS:
        raise ThrsimInputError(f"--definition must be one of {', '.join(DEFINITIONS)}; got {definition!r}")
    frame = app_frame(landmarks, side=side, plane=plane)
    cup_axis = _vector(axis, "--axis")
    all_angles = {d: angles_in_frame(cup_axis, frame, d) for d in DEFINITIONS}
    zone = safe_zone_status(*all_angles["radiographic"], SafeZone())
    inclination, anteversion = all_angles[definition]
    result = {
        "side": side,
        "plane": plane,
        "definition": definition,
        "inclination_deg": inclination,
        "anteversion_deg": anteversion,
        **{d: {"inclination_deg": i, "anteversion_deg": a} for d, (i, a) in all_angles.items()},
        "safe_zone": zone.as_dict(),
    }
    if as_json:
        print_json(result)
        return
    print_table(
        f"cup angles ({side} hip, {definition})",
        {f"{d} inclination / anteversion (deg)": f"{i:.2f} / {a:.2f}" for d, (i, a) in all_angles.items()}
        | {"Lewinnek safe zone": "inside" if zone.inside else f"outside by {zone.distance_deg:.2f} deg", "ray colour": zone.colour},
    )


@app.command("convert")
def convert(
    inclination: float = typer.Option(..., "--inclination", help="inclination in degrees [0, 90]", metavar="DEG"),
    anteversion: float = typer.Option(..., "--anteversion", help="anteversion in degrees [-90, 90]", metavar="DEG"),
    source: str = typer.Option("radiographic", "--from", help="definition of the given angles"),
    target: str = typer.Option("operative", "--to", help="definition to convert to"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Convert (inclination, anteversion) between Murray's radiographic, operative and anatomic definitions."""
    converted = convert_angles(inclination, anteversion, source, target)
    result = {"from": source, "to": target, "inclination_deg": converted[0], "anteversion_deg": converted[1]}
    if as_json:
        print_json(result)
        return
    print_table(
        f"{source} {inclination:g} / {anteversion:g} deg as {target}",
        {"inclination (deg)": converted[0], "anteversion (deg)": converted[1]},
    )
