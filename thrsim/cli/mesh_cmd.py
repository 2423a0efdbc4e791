"""``thrsim mesh``: generate a bone (the thesis's patch or the layered socket), or read and validate a mesh file."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path

import typer

from thrsim.cli.output import console, print_json, print_table
from thrsim.cli.socket_window import WINDOW_HELP, WINDOW_METAVAR, window_settings
from thrsim.config import BonePatchConfig, SocketConfig
from thrsim.errors import ThrsimInputError
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.mesh_io import WRITABLE_SUFFIXES, read_mesh, write_mesh
from thrsim.geometry.socket import generate_socket


def mesh(
    bone_kind: str = typer.Option("patch", "--bone", help="which bone: patch (the thesis's 2 mm shell) or socket (the layered acetabulum)"),
    socket_diameter: float | None = typer.Option(
        None, "--socket-diameter", help="native socket diameter in mm, 40 to 60 (socket only; default 46)", metavar="MM"
    ),
    window: str | None = typer.Option(None, "--window", help=WINDOW_HELP, metavar=WINDOW_METAVAR),
    element_size: float | None = typer.Option(None, "--element-size", help="global element size in mm (default 0.45)", metavar="MM"),
    side: str = typer.Option("right", "--side", help="hip side: right, or left (mirror across the sagittal plane)"),
    thickness: float | None = typer.Option(None, "--thickness", help="shell thickness in mm (default 2.0)", metavar="MM"),
    half_angle: float | None = typer.Option(None, "--half-angle", help="patch half-angle about the pole in degrees", metavar="DEG"),
    from_file: Path | None = typer.Option(
        None, "--from", help="read and validate this mesh instead (.inp C3D4, .msh, .vtu, .h5, ...)", metavar="FILE"
    ),
    units: str = typer.Option("mm", "--units", help="coordinate units of --from/--out exchange files: mm or m (.h5 is always m)"),
    out: Path | None = typer.Option(None, "--out", help=f"write the mesh ({', '.join(WRITABLE_SUFFIXES)})", metavar="FILE"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Generate a bone mesh (the patch, or the layered socket) or validate one read --from a file, and summarise it."""
    if bone_kind not in ("patch", "socket"):
        raise ThrsimInputError(f"--bone must be patch or socket, got {bone_kind!r}")
    if units not in ("mm", "m"):
        raise ThrsimInputError(f"--units must be mm or m, got {units!r}")
    if side not in ("right", "left"):
        raise ThrsimInputError(f"--side must be right or left, got {side!r}")
    if out is not None and out.suffix.lower() not in WRITABLE_SUFFIXES:
        raise ThrsimInputError(f"{out}: unsupported output format; use one of {', '.join(WRITABLE_SUFFIXES)}")

    if from_file is not None:
        given = [
            flag
            for flag, value in (
                ("--element-size", element_size),
                ("--thickness", thickness),
                ("--half-angle", half_angle),
                ("--socket-diameter", socket_diameter),
                ("--window", window),
            )
            if value is not None
        ]
        if given:
            raise ThrsimInputError(f"{', '.join(given)} only apply to a generated mesh, not to --from {from_file}")
        bone = read_mesh(from_file, units=units)  # type: ignore[arg-type]
        if side == "left":
            bone = bone.mirrored(axis=0)
        source = str(from_file)
    else:
        bone = _generate(bone_kind, side, element_size, thickness, half_angle, socket_diameter, window_settings(window), quiet=as_json)
        bone.validate(source="generated mesh")
        source = f"generated {bone_kind}"

    summary = {"source": source, "bone": bone_kind if from_file is None else "file", "side": side, **bone.summary()}
    if out is not None:
        write_mesh(bone, out, units=units, metadata={"source": source, "side": side})  # type: ignore[arg-type]
        summary["out"] = str(out)
    if as_json:
        print_json(summary)
        return
    quality = summary.pop("quality")
    sets = summary.pop("node_sets")
    materials = summary.pop("materials")
    summary |= {f"elements of {name}": count for name, count in materials.items()}
    box = summary.pop("bounding_box_mm")
    print_table("bone mesh", summary | {f"nodes in set {k}": v for k, v in sets.items()})
    print_table(
        "quality", quality | {"bbox min (mm)": [round(v, 3) for v in box["min"]], "bbox max (mm)": [round(v, 3) for v in box["max"]]}
    )


def _generate(
    bone_kind: str,
    side: str,
    element_size: float | None,
    thickness: float | None,
    half_angle: float | None,
    socket_diameter: float | None,
    window: dict[str, float],
    quiet: bool,
) -> TetMesh:
    """The generated bone the options ask for (flags that belong to the other bone refused)."""
    generate: Callable[[], TetMesh]
    if bone_kind == "socket":
        wrong = [flag for flag, value in (("--thickness", thickness), ("--half-angle", half_angle)) if value is not None]
        if wrong:
            raise ThrsimInputError(f"{', '.join(wrong)} only apply to --bone patch")
        settings = {"side": side, "element_size_mm": element_size, "socket_diameter_mm": socket_diameter, **window}
        generate, what = (
            partial(generate_socket, SocketConfig(**{k: v for k, v in settings.items() if v is not None})),
            "the layered socket",
        )
    else:
        if socket_diameter is not None or window:
            raise ThrsimInputError("--socket-diameter and --window only apply to --bone socket")
        settings = {"side": side, "element_size_mm": element_size, "thickness_mm": thickness, "half_angle_deg": half_angle}
        generate, what = (
            partial(generate_bone_patch, BonePatchConfig(**{k: v for k, v in settings.items() if v is not None})),
            "the bone patch",
        )
    if quiet:
        return generate()
    with console.status(f"meshing {what} with gmsh"):
        return generate()
