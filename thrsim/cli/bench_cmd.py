"""``thrsim bench``: performance figures as JSON."""

from __future__ import annotations

import typer

from thrsim.cli.output import print_json


def bench(
    element_size: float = typer.Option(0.45, "--element-size", help="bone mesh element size in mm", metavar="MM"),
    frames: int = typer.Option(3, "--frames", min=1, help="solver frames to time (after a warm-up frame)"),
) -> None:
    """Time mesh generation and the explicit solver; print one JSON object."""
    from thrsim.bench import run_benchmarks  # Numba and gmsh: loaded only when benchmarking

    print_json(run_benchmarks(element_size, frames))
