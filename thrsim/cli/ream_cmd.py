"""``thrsim ream``: a learned reaming rollout written as a ParaView time series and a JSON summary."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from thrsim.cli.output import print_json, print_table


def ream(
    inclination: float = typer.Option(
        15.0, "--inclination", help="reamer inclination γ in degrees [0, 90], from the patch's axis (the default case's)", metavar="DEG"
    ),
    anteversion: float = typer.Option(
        30.0, "--anteversion", help="reamer anteversion θ in degrees [0, 360] (the default case's)", metavar="DEG"
    ),
    out: Path = typer.Option(
        Path("runs/ream"),
        "--out",
        help="output folder (created, with its parents): ream.pvd, bone_*.vtu, reamer_*.vtu, ream.json",
        metavar="DIR",
    ),
    force: float = typer.Option(230.0, "--force", help="axial push force in N", metavar="N"),
    frames: int = typer.Option(120, "--frames", help="frames at 60 per second", metavar="N"),
    side: str = typer.Option("right", "--side", help="hip side: right or left"),
    model: Optional[Path] = typer.Option(None, "--model", help="model directory (default: the shipped model)", metavar="MODEL_DIR"),
    threads: int = typer.Option(1, "--threads", help="PyTorch and BLAS threads", metavar="N"),
    png: Optional[Path] = typer.Option(None, "--png", help="also draw the last frame (offscreen OpenGL) to this PNG", metavar="FILE.png"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Ream with the learned simulator (autonomous: the regressor advances the reamer) and write the series."""
    from thrsim.errors import ThrsimInputError

    if threads < 1:
        raise ThrsimInputError(f"--threads must be at least 1, got {threads}")
    from thrsim.learn.ream import ream as run_ream

    summary = run_ream(inclination, anteversion, force, frames, side, out, model, png, threads)
    if as_json:
        print_json(summary)
    else:
        print_table(
            f"learned reaming written to {out}",
            {k: summary[k] for k in ("frames", "removed", "removed_volume_mm3", "depth_mm", "ms_per_frame_median")},
        )
