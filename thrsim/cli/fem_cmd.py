"""``thrsim fem``: one ground-truth reaming case with the explicit solver, written as an HDF5 case file."""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import typer
from pydantic import ValidationError
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from thrsim.cli.aim import CUP_ANTEVERSION, CUP_INCLINATION, GAMMA_HELP, THETA_HELP, resolve_aim
from thrsim.cli.output import err_console, format_validation_error, print_json, print_table
from thrsim.cli.socket_window import WINDOW_HELP, WINDOW_METAVAR, window_settings
from thrsim.config import (
    CANCELLOUS_PRESETS,
    FRAME_RATE_HZ,
    PUSH_FORCE_N,
    ContactConfig,
    ReamingCaseConfig,
    head_diameter_for_size,
    load_case_config,
)
from thrsim.data.checkpoint import CHECKPOINT_EVERY_S, checkpoint_path
from thrsim.errors import ThrsimInputError

MAX_CHECKPOINT_EVERY_S = 7 * 24 * 3600.0
# the help shows the configuration's defaults, not copies of them that can fall behind
_CONTACT = ContactConfig()


def fem(
    inclination: float | None = typer.Option(None, "--inclination", help=GAMMA_HELP, metavar="DEG"),
    anteversion: float | None = typer.Option(None, "--anteversion", help=THETA_HELP, metavar="DEG"),
    cup_inclination: float | None = CUP_INCLINATION,
    cup_anteversion: float | None = CUP_ANTEVERSION,
    out: Path = typer.Option(..., "--out", help="case file to write (.h5)", metavar="CASE.h5"),
    frames: int | None = typer.Option(
        None,
        "--frames",
        help=f"frames to simulate at {FRAME_RATE_HZ:g} per simulated second [default: {ReamingCaseConfig.model_fields['frames'].default}]",
    ),
    force: float | None = typer.Option(None, "--force", help=f"axial push force in N [default: {PUSH_FORCE_N:g}]"),
    feed: float | None = typer.Option(
        None,
        "--feed",
        help="feed control instead: the reamer advances at this rate in mm/s and the push it takes is recorded",
        metavar="MM_S",
    ),
    start_from: Path | None = typer.Option(
        None, "--start-from", help="start from this case's last frame (same bone mesh, same thrsim): chains reamer sizes", metavar="CASE.h5"
    ),
    bone: str = typer.Option("patch", "--bone", help="which bone: patch (the thesis's 2 mm shell) or socket (the layered acetabulum)"),
    reamer_diameter: float | None = typer.Option(
        None,
        "--reamer-diameter",
        help="reamer size in mm (the diameter its teeth cut), 31 to 80; its teeth follow the size [default: the thesis's 45 mm head]",
        metavar="MM",
    ),
    pre_ream: float | None = typer.Option(
        None, "--pre-ream", help="start from a socket reamed geometrically to this diameter in mm (socket only)", metavar="MM"
    ),
    pre_ream_centre: str | None = typer.Option(
        None, "--pre-ream-centre", help="the prepared cavity's centre X,Y,Z in mm, bone frame [default: 0,0,0]", metavar="X,Y,Z"
    ),
    reamer_centre: str | None = typer.Option(
        None,
        "--reamer-centre",
        help="the point X,Y,Z in mm (bone frame) the reamer's axis passes through: medialise or raise the cavity (socket only) "
        "[default: 0,0,0, the native socket's centre]",
        metavar="X,Y,Z",
    ),
    socket_diameter: float | None = typer.Option(
        None, "--socket-diameter", help="native socket diameter in mm, 40 to 60 (socket only) [default: 46]", metavar="MM"
    ),
    window: str | None = typer.Option(None, "--window", help=WINDOW_HELP, metavar=WINDOW_METAVAR),
    cancellous: str | None = typer.Option(
        None, "--cancellous", help="cancellous bone behind the subchondral plate: normal or osteoporotic (socket only) [default: normal]"
    ),
    element_size: float | None = typer.Option(None, "--element-size", help="bone mesh element size in mm [default: 0.45]", metavar="MM"),
    side: str | None = typer.Option(None, "--side", help="hip side: right or left [default: right]"),
    failure_displacement: float | None = typer.Option(
        None, "--failure-displacement", help="damage u_f in mm (Table 8: 0.5, text: 0.1)", metavar="MM"
    ),
    target_dt: float | None = typer.Option(None, "--target-dt", help="time step in s reached by mass scaling", metavar="S"),
    contact_factor: float | None = typer.Option(
        None, "--contact-factor", help=f"contact penalty factor β (k_i = β·m_i/Δt²) [default: {_CONTACT.penalty_factor:g}]"
    ),
    cutting_energy: float | None = typer.Option(
        None,
        "--cutting-energy",
        help=f"bone's specific cutting energy in J/mm³ [default: {_CONTACT.specific_cutting_energy_j_m3 / 1e9:g}]",
        metavar="J_MM3",
    ),
    effective_mass: float | None = typer.Option(
        None, "--effective-mass", help="hand-held reamer's effective axial mass in kg [default: 2]", metavar="KG"
    ),
    axial_damping: float | None = typer.Option(
        None, "--axial-damping", help="arm and driver damping along the axis in N·s/m", metavar="NS_M"
    ),
    threads: int | None = typer.Option(None, "--threads", help="solver threads (default: all cores)"),
    checkpoint_every: float = typer.Option(
        CHECKPOINT_EVERY_S,
        "--checkpoint-every",
        help="seconds of solving between checkpoints (CASE.h5.resume; rerun the same command to resume after a kill; 0: every frame)",
        metavar="S",
    ),
    config: Path | None = typer.Option(
        None, "--config", help="JSON file of case settings (any field of ReamingCaseConfig, nested); flags override it", metavar="FILE"
    ),
    mesh_file: Path | None = typer.Option(
        None, "--mesh", help="bone mesh to use instead of the generated patch (validated like `thrsim mesh --from`, mm)", metavar="FILE"
    ),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Simulate one reaming case (the thesis's settings by default) and write its case file atomically.

    Aim the reamer with the bone frame's --inclination/--anteversion (γ, θ, as the case file stores
    them) or with the clinical --cup-inclination/--cup-anteversion (radiographic, anterior pelvic
    plane, as the trainer shows them; see `thrsim ream --help`), one pair.
    """
    if not 0.0 <= checkpoint_every <= MAX_CHECKPOINT_EVERY_S:
        raise ThrsimInputError(
            f"--checkpoint-every must be a number of seconds from 0 to {MAX_CHECKPOINT_EVERY_S:g} (a week), got {checkpoint_every:g}"
        )
    if force is not None and feed is not None:
        raise ThrsimInputError("give --force (force control) or --feed (feed control), not both")
    if start_from is not None and not start_from.is_file():
        raise ThrsimInputError(f"--start-from {start_from}: no such case file")
    aim = resolve_aim(inclination, anteversion, cup_inclination, cup_anteversion)
    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise ThrsimInputError(f"{out}: the case file must end in .h5")
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir() or not os.access(folder, os.W_OK):
        raise ThrsimInputError(f"{out}: output folder {folder} does not exist or is not writable")
    if bone not in ("patch", "socket"):
        raise ThrsimInputError(f"--bone must be patch or socket, got {bone!r}")
    if bone == "patch" and any(value is not None for value in (socket_diameter, cancellous, window, reamer_centre)):
        raise ThrsimInputError("--socket-diameter, --window, --reamer-centre and --cancellous only apply to --bone socket")
    socket_window = {f"socket.{key}": value for key, value in window_settings(window).items()}
    if cancellous is not None and cancellous not in CANCELLOUS_PRESETS:
        raise ThrsimInputError(f"--cancellous must be one of {', '.join(CANCELLOUS_PRESETS)}, got {cancellous!r}")
    side_of = "socket" if bone == "socket" else "bone"
    given = {  # each setting a flag sets: the flag, and its value in the configuration's units (None: not given)
        "inclination_deg": ("--inclination", aim.inclination_deg),
        "anteversion_deg": ("--anteversion", aim.anteversion_deg),
        "frames": ("--frames", frames),
        "force_n": ("--force", force),
        "feed_mm_s": ("--feed", feed),
        "start_from": ("--start-from", None if start_from is None else str(start_from)),
        "bone_kind": ("--bone", bone),
        f"{side_of}.element_size_mm": ("--element-size", element_size),
        f"{side_of}.side": ("--side", side),
        "socket.socket_diameter_mm": ("--socket-diameter", socket_diameter),
        **{dotted: ("--window", value) for dotted, value in socket_window.items()},
        "cancellous": ("--cancellous", None if cancellous is None else CANCELLOUS_PRESETS[cancellous].model_dump()),
        "reamer.head_diameter_mm": ("--reamer-diameter", None if reamer_diameter is None else head_diameter_for_size(reamer_diameter)),
        "pre_ream_mm": ("--pre-ream", pre_ream),
        "pre_ream_centre_mm": ("--pre-ream-centre", None if pre_ream_centre is None else _point_mm(pre_ream_centre, "--pre-ream-centre")),
        "reamer_centre_mm": ("--reamer-centre", None if reamer_centre is None else _point_mm(reamer_centre, "--reamer-centre")),
        "damage.displacement_at_failure_m": (
            "--failure-displacement",
            None if failure_displacement is None else failure_displacement * 1e-3,
        ),
        "solver.target_dt_s": ("--target-dt", target_dt),
        "solver.threads": ("--threads", threads),
        "contact.penalty_factor": ("--contact-factor", contact_factor),
        "contact.specific_cutting_energy_j_m3": ("--cutting-energy", None if cutting_energy is None else cutting_energy * 1e9),
        "hold.effective_mass_kg": ("--effective-mass", effective_mass),
        "hold.axial_damping_n_s_m": ("--axial-damping", axial_damping),
    }
    try:
        case = load_case_config(None if config is None else str(config), {dotted: value for dotted, (_, value) in given.items()})
    except ValidationError as error:  # the line names the flag beside each setting it refuses that a flag set
        line = format_validation_error(error)
        for dotted, (flag, value) in given.items():
            if value is not None:
                line = re.sub(rf"(?<=: |; ){re.escape(dotted)}:", f"{dotted} ({flag}):", line)
        raise ThrsimInputError(line) from None
    bone_mesh = None
    if mesh_file is not None:
        from thrsim.geometry.mesh_io import read_mesh

        bone_mesh = read_mesh(mesh_file)
        if len(bone_mesh.fixed_nodes) == 0:
            raise ThrsimInputError(f"{mesh_file}: the mesh has no fixed nodes (a node set named 'fixed')")
    from thrsim.data.ground_truth import run_case  # Numba: loaded only when a case runs

    columns = (TextColumn("reaming"), BarColumn(), MofNCompleteColumn(), TextColumn("frames"), TimeElapsedColumn(), TimeRemainingColumn())
    with Progress(*columns, console=err_console, transient=as_json) as bar:
        task = bar.add_task("frames", total=case.frames)
        summary = run_case(
            case, out, progress=lambda done, total: bar.update(task, completed=done), mesh=bone_mesh,
            checkpoint=checkpoint_path(out), checkpoint_every_s=checkpoint_every,
        )  # fmt: skip
    summary = {**aim.as_dict(), **summary}
    if as_json:
        print_json(summary)
    else:
        print_table("reaming case", summary)


def _point_mm(text: str, flag: str) -> list[float]:
    """Three comma-separated finite numbers (mm)."""
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ThrsimInputError(f"{flag} must be three numbers X,Y,Z in mm, got {text!r}")
    return values
