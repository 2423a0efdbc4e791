"""``thrsim mesh``: generate the default acetabular bone patch, or read and validate a mesh file."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from thrsim.cli.output import console, print_json, print_table
from thrsim.config import BonePatchConfig
from thrsim.errors import ThrsimInputError
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.geometry.mesh_io import WRITABLE_SUFFIXES, read_mesh, write_mesh


def mesh(
    element_size: Optional[float] = typer.Option(None, "--element-size", help="global element size in mm (default 0.45)", metavar="MM"),
    side: str = typer.Option("right", "--side", help="hip side: right, or left (mirror across the sagittal plane)"),
    thickness: Optional[float] = typer.Option(None, "--thickness", help="shell thickness in mm (default 2.0)", metavar="MM"),
    half_angle: Optional[float] = typer.Option(None, "--half-angle", help="patch half-angle about the pole in degrees", metavar="DEG"),
    from_file: Optional[Path] = typer.Option(
        None, "--from", help="read and validate this mesh instead (.inp C3D4, .msh, .vtu, .h5, ...)", metavar="FILE"
    ),
    units: str = typer.Option("mm", "--units", help="coordinate units of --from/--out exchange files: mm or m (.h5 is always m)"),
    out: Optional[Path] = typer.Option(None, "--out", help=f"write the mesh ({', '.join(WRITABLE_SUFFIXES)})", metavar="FILE"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Generate the default bone mesh or validate one read --from a file, and summarise it."""
    if units not in ("mm", "m"):
        raise ThrsimInputError(f"--units must be mm or m, got {units!r}")
    if side not in ("right", "left"):
        raise ThrsimInputError(f"--side must be right or left, got {side!r}")
    if out is not None and out.suffix.lower() not in WRITABLE_SUFFIXES:
        raise ThrsimInputError(f"{out}: unsupported output format; use one of {', '.join(WRITABLE_SUFFIXES)}")

    if from_file is not None:
        given = [
            flag
            for flag, value in (("--element-size", element_size), ("--thickness", thickness), ("--half-angle", half_angle))
            if value is not None
        ]
        if given:
            raise ThrsimInputError(f"{', '.join(given)} only apply to a generated mesh, not to --from {from_file}")
        bone = read_mesh(from_file, units=units)  # type: ignore[arg-type]
        if side == "left":
            bone = bone.mirrored(axis=0)
        source = str(from_file)
    else:
        overrides = {"side": side}
        for key, value in (("element_size_mm", element_size), ("thickness_mm", thickness), ("half_angle_deg", half_angle)):
            if value is not None:
                overrides[key] = value
        config = BonePatchConfig(**overrides)
        if as_json:
            bone = generate_bone_patch(config)
        else:
            with console.status("meshing the bone patch with gmsh"):
                bone = generate_bone_patch(config)
        bone.validate(source="generated mesh")
        source = "generated"

    summary = {"source": source, "side": side, **bone.summary()}
    if out is not None:
        write_mesh(bone, out, units=units, metadata={"source": source, "side": side})  # type: ignore[arg-type]
        summary["out"] = str(out)
    if as_json:
        print_json(summary)
        return
    quality = summary.pop("quality")
    sets = summary.pop("node_sets")
    box = summary.pop("bounding_box_mm")
    print_table("bone mesh", summary | {f"nodes in set {k}": v for k, v in sets.items()})
    print_table(
        "quality", quality | {"bbox min (mm)": [round(v, 3) for v in box["min"]], "bbox max (mm)": [round(v, 3) for v in box["max"]]}
    )
