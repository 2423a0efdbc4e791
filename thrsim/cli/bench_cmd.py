"""``thrsim bench``: performance figures as JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from thrsim.cli.output import print_json


def bench(
    element_size: float = typer.Option(0.45, "--element-size", help="bone mesh element size in mm", metavar="MM"),
    frames: int = typer.Option(3, "--frames", min=1, help="solver frames to time (after a warm-up frame)"),
    learned: bool = typer.Option(False, "--learned", help="also time the learned simulator (production step, the thesis's way, a 4x larger mesh)"),
    model: Optional[Path] = typer.Option(None, "--model", help="model directory to time (default: initial weights on the default mesh)", metavar="MODEL_DIR"),
) -> None:
    """Time mesh generation and the explicit solver; print one JSON object."""
    from thrsim.bench import run_benchmarks  # Numba and gmsh: loaded only when benchmarking

    result = run_benchmarks(element_size, frames)
    if learned:
        import torch

        from thrsim.learn.bench import run_learned_benchmarks
        from thrsim.learn.model_dir import load_model

        torch.set_num_threads(1)
        loaded = load_model(model) if model is not None else None
        result["learned"] = run_learned_benchmarks(loaded, solver_seconds_per_frame=result["solver"]["seconds_per_frame"])
    print_json(result)
