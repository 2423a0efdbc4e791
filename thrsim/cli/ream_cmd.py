"""``thrsim ream``: a learned reaming rollout written as a ParaView time series and a JSON summary."""

from __future__ import annotations

from pathlib import Path

import typer

from thrsim.cli.aim import CUP_ANTEVERSION, CUP_INCLINATION, GAMMA_HELP, THETA_HELP, resolve_aim
from thrsim.cli.output import check_threads, print_json
from thrsim.config import FRAME_RATE_HZ, PUSH_FORCE_N
from thrsim.errors import ThrsimInputError

#: the aim when none is given: the default case's γ, θ
DEFAULT_AIM_DEG = (15.0, 30.0)


def ream(
    inclination: float | None = typer.Option(
        None, "--inclination", help=f"{GAMMA_HELP} [default: {DEFAULT_AIM_DEG[0]:g}, the default case's]", metavar="DEG"
    ),
    anteversion: float | None = typer.Option(
        None, "--anteversion", help=f"{THETA_HELP} [default: {DEFAULT_AIM_DEG[1]:g}, the default case's]", metavar="DEG"
    ),
    cup_inclination: float | None = CUP_INCLINATION,
    cup_anteversion: float | None = CUP_ANTEVERSION,
    out: Path = typer.Option(
        Path("runs/ream"),
        "--out",
        help="output folder (created, with its parents): ream.pvd (open it in ParaView), bone_*.vtu, reamer_*.vtu, ream.json",
        metavar="DIR",
    ),
    force: float = typer.Option(PUSH_FORCE_N, "--force", help="axial push force in N", metavar="N"),
    frames: int = typer.Option(
        120,
        "--frames",
        help=f"frames at {FRAME_RATE_HZ:g} per second, per reamer on the socket (the run stops earlier where the reamer goes through the bone)",
        metavar="N",
    ),
    side: str = typer.Option("right", "--side", help="hip side: right or left"),
    model: Path | None = typer.Option(None, "--model", help="model directory (default: the shipped model)", metavar="MODEL_DIR"),
    threads: int = typer.Option(1, "--threads", help="PyTorch and BLAS threads", metavar="N"),
    png: Path | None = typer.Option(
        None,
        "--png",
        help="also draw (offscreen OpenGL) the last frame that still shows the bone to this PNG (a run that goes through the bone ends with little or none left)",
        metavar="FILE.png",
    ),
    bone: str = typer.Option(
        "patch", "--bone", help="patch (the shipped model's) or socket (the whole socket: the shipped socket model, or a socket --model)"
    ),
    reamers: str | None = typer.Option(
        None, "--reamers", help="socket: reamer sizes in mm, taken in turn, each until seated (e.g. 46,48,50)", metavar="LIST"
    ),
    element_size: float | None = typer.Option(
        None, "--element-size", help="socket: the whole socket's element size in mm [default: 1.5]", metavar="MM"
    ),
    cancellous: str = typer.Option("normal", "--cancellous", help="socket: cancellous bone, normal or osteoporotic"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Ream with the learned simulator (autonomous: the regressor advances the reamer) and write the series.

    Aim the reamer with the bone frame's --inclination/--anteversion (γ, θ: the reamer axis relative to
    the socket axis, as the case files store it) or with the clinical --cup-inclination/--cup-anteversion
    (radiographic, in the anterior pelvic plane, as the trainer shows them), not both. The trainer places
    the bone with γ 0 at the safe zone's centre, cup 40°/15°: cup 45°/20° is γ 6.9°, θ 330.1°, and the
    default γ 15°, θ 30° is cup 54.9°/11.2°.
    """
    check_threads(threads)
    aim = resolve_aim(inclination, anteversion, cup_inclination, cup_anteversion, default=DEFAULT_AIM_DEG)
    if bone not in ("patch", "socket"):
        raise ThrsimInputError(f"--bone must be patch or socket, got {bone!r}")
    if bone == "patch":
        if reamers is not None or element_size is not None:
            raise ThrsimInputError("--reamers and --element-size are the socket's: add --bone socket")
        from thrsim.learn.ream import ream as run_ream

        summary = run_ream(aim.inclination_deg, aim.anteversion_deg, force, frames, side, out, model, png, threads)
    else:
        if png is not None:
            raise ThrsimInputError("--png draws the patch only; open the socket's series in ParaView")
        from thrsim.learn.ream import SOCKET_ELEMENT_SIZE_MM, parse_reamers, ream_socket

        sizes = parse_reamers(reamers if reamers is not None else "48")
        size_mm = SOCKET_ELEMENT_SIZE_MM if element_size is None else element_size
        summary = ream_socket(
            aim.inclination_deg, aim.anteversion_deg, force, frames, side, out, model, sizes, size_mm, cancellous, threads
        )
    if as_json:
        print_json(summary)
    elif bone == "socket":
        typer.echo("\n".join(describe_socket(summary)))
    else:
        typer.echo("\n".join(describe(summary)))


def describe_socket(summary: dict) -> list[str]:
    """A socket run in a few lines: each reamer's frames, how it ended, what it removed."""
    lines = [
        f"learned reaming of the whole socket: γ {summary['inclination_deg']:g}°, θ {summary['anteversion_deg']:g}°, "
        f"{summary['force_n']:g} N, {summary['side']} hip, {summary['elements']} elements ({summary['element_size_mm']:g} mm)"
    ]
    for step in summary["reamers"]:
        reaction = step["reaction_n_mean"]
        flags = f"; outside what the model learned: {', '.join(step['out_of_range'])}" if step["out_of_range"] else ""
        lines.append(
            f"reamer {step['reamer_mm']:g} mm: {step['frames']} frames ({step['seconds']:.1f} s), {step['ended']}, "
            f"{step['removed_volume_mm3']:.0f} mm³ removed so far"
            + ("" if reaction is None else f", bone reaction {reaction:.1f} N mean")
            + flags
        )
    lines.append(f"stopped: {summary['end_reason_text']}; {summary['ms_per_frame_median']:.1f} ms per frame (median)")
    lines.append(f"open the series in {summary['open_with']}")
    return lines


def describe(summary: dict) -> list[str]:
    """The run in a few lines: the aim, why it stopped, what was removed, the picture, how to open the series."""
    cup = summary["cup_inclination_deg"], summary["cup_anteversion_deg"]
    cup_text = (
        "no clinical angles: the cup axis points into the pelvis" if cup[0] is None else f"cup {cup[0]:.1f}°/{cup[1]:.1f}° radiographic"
    )
    removed, elements = summary["removed"], summary["elements"]
    lines = [
        f"learned reaming: γ {summary['inclination_deg']:g}°, θ {summary['anteversion_deg']:g}° ({cup_text}), "
        f"{summary['force_n']:g} N, {summary['side']} hip",
        f"stopped: {summary['end_reason_text']}",
        f"frames: {summary['frames']} run of {summary['frames_requested']} asked ({summary['frame_rate_hz']:g} per second)",
        f"removed: {removed} of {elements} elements ({100 * removed / elements:.1f}%, {summary['removed_volume_mm3']:.1f} mm³)"
        + (": every element, the reamer went through the whole bone patch" if summary["removed_all"] else ""),
        f"depth: {summary['depth_mm']:.2f} mm; {summary['ms_per_frame_median']:.1f} ms per frame (median)",
    ]
    if "png" in summary:
        from thrsim.learn.ream import PICTURE_BONE_FRACTION

        frame, last = summary["png_frame"], summary["frames"]
        shown = (
            "the last frame"
            if frame == last
            else f"frame {frame}, the last with {PICTURE_BONE_FRACTION:.0%} of the bone or more (frame {last} has {elements - removed} elements left)"
        )
        lines.append(f"picture: {summary['png']} shows {shown}")
    lines.append(f"open the series in {summary['open_with']}")
    return lines
