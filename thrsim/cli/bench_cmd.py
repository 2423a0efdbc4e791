"""``thrsim bench``: performance figures as JSON."""

from __future__ import annotations

from pathlib import Path

import typer

from thrsim.app.reaming_bench import WHOLE_REAMING_FRAMES, WHOLE_REAMING_MM
from thrsim.cli.output import print_json
from thrsim.errors import ThrsimInputError


def bench(
    element_size: float = typer.Option(0.45, "--element-size", help="bone mesh element size in mm", metavar="MM"),
    frames: int = typer.Option(3, "--frames", min=1, help="solver frames to time (after a warm-up frame)"),
    learned: bool = typer.Option(
        False, "--learned", help="also time the learned simulator (production step, the thesis's way, a 4x larger mesh)"
    ),
    model: Path | None = typer.Option(
        None, "--model", help="model directory to time (default: initial weights on the default mesh)", metavar="MODEL_DIR"
    ),
    socket: bool = typer.Option(
        False,
        "--socket",
        help="also time the socket: a window at a set feed and the whole socket at 1.5 mm, per active element against the patch; "
        "with --learned, the socket model's step on the whole socket at 1.5 and 1.0 mm, tool-forced and pushed with two reamers "
        "(the shipped socket model, or --model: a socket model to time)",
    ),
    browser: bool = typer.Option(False, "--browser", help="also time the trainer page's drawing in headless Chromium (software WebGL)"),
    browser_only: bool = typer.Option(False, "--browser-only", help="time only the trainer page's drawing (no mesh, no solver)"),
    browser_seconds: float = typer.Option(10.0, "--browser-seconds", min=1.0, help="how long to count the page's frames", metavar="S"),
    reaming_page: bool = typer.Option(
        False,
        "--reaming-page",
        help="also time the reaming page (simulator frames delivered, bytes per frame, pose-to-page latency, drawing) with --model or the shipped model; "
        "a whole-socket --model first reams the socket whole (--reamers, --reaming-frames): its worst tick, the drawn bone's lag, inputs in order",
    ),
    reamers: str | None = typer.Option(
        None,
        "--reamers",
        help="--reaming-page with a whole-socket --model: the reamer sequence of the whole reaming, growing mm [default: "
        + ",".join(map(str, WHOLE_REAMING_MM))
        + "]",
        metavar="LIST",
    ),
    reaming_frames: int | None = typer.Option(
        None,
        "--reaming-frames",
        min=1,
        max=100_000,
        help=f"--reaming-page with a whole-socket --model: simulator frames of the whole reaming, shared among the reamers [default: {WHOLE_REAMING_FRAMES}]",
        metavar="N",
    ),
    socket_element_size: float | None = typer.Option(
        None,
        "--socket-element-size",
        help="--reaming-page with a whole-socket --model: the socket's element size, as thrsim serve's",
        metavar="MM",
    ),
    compile_network: bool = typer.Option(
        True,
        "--compile/--no-compile",
        help="--reaming-page: the served network compiled, as thrsim serve runs it (--no-compile: the server starts sooner, steps slower); "
        "--socket --learned: the pushed whole socket timed compiled too",
    ),
    headset: bool = typer.Option(
        False,
        "--headset",
        help="also time the reaming page's two eyes in an emulated Meta Quest 3 at its per-eye resolution (iwer, software WebGL), "
        "with its draw calls and triangles",
    ),
    as_json: bool = typer.Option(True, "--json", help="print one JSON object on stdout (bench's only output, so the default)"),
) -> None:
    """Time mesh generation and the explicit solver (and the trainer pages); print one JSON object."""
    whole = _whole_reaming_settings(model, reaming_page, reamers, reaming_frames, socket_element_size) | {"compile": compile_network}
    if browser_only:
        if learned or socket:
            raise ThrsimInputError("--browser-only times only the pages: drop --learned and --socket")
        import os
        import platform

        from thrsim.app.drawing_bench import time_drawing
        from thrsim.app.live import versions

        machine = {"cpu_count": os.cpu_count(), "platform": platform.platform()}
        result = {"machine": machine, "versions": versions(), "browser": time_drawing(browser_seconds)}
        if reaming_page:
            result["reaming_page"] = _reaming_page(model, browser_seconds, whole)
        if headset:
            result["headset"] = _headset(browser_seconds)
        print_json(result)
        return
    from thrsim.bench import run_benchmarks  # Numba and gmsh: loaded only when benchmarking

    result = run_benchmarks(element_size, frames, socket=socket)
    if browser:
        from thrsim.app.drawing_bench import time_drawing

        result["browser"] = time_drawing(browser_seconds)
    if learned:
        import torch

        from thrsim.learn.bench import run_learned_benchmarks
        from thrsim.learn.model_dir import load_model

        torch.set_num_threads(1)
        loaded = load_model(model) if model is not None else None
        if socket:
            from thrsim.learn.bench import time_socket_steps
            from thrsim.learn.model_dir import SHIPPED_SOCKET_MODEL, reads_any_mesh

            socket_model = loaded if loaded is not None and reads_any_mesh(loaded.settings) else load_model(SHIPPED_SOCKET_MODEL)
            loaded = None if loaded is socket_model else loaded
            result["learned_socket"] = {"whole_socket": time_socket_steps(socket_model, compile=compile_network)}
        result["learned"] = run_learned_benchmarks(loaded, solver_seconds_per_frame=result["solver"]["seconds_per_frame"])
    if reaming_page:
        result["reaming_page"] = _reaming_page(model, browser_seconds, whole)
    if headset:
        result["headset"] = _headset(browser_seconds)
    print_json(result)


def _headset(seconds: float) -> dict:
    from thrsim.app.drawing_bench import check_browser
    from thrsim.app.headset_bench import IWER, time_headset

    check_browser()
    if not IWER.exists():
        raise ThrsimInputError(f"--headset needs the iwer emulator ({IWER}): run npm ci in thrsim/app/static (./install.sh does)")
    return time_headset(seconds)


def _whole_reaming_settings(
    model: Path | None, reaming_page: bool, reamers: str | None, frames: int | None, element_size: float | None
) -> dict:
    """The whole reaming's flags checked before anything runs: a whole-socket model's only, the reamers
    ones the page offers, the element size one thrsim serve takes; the figures :func:`time_reaming_page` takes."""
    given = [
        flag
        for flag, value in (("--reamers", reamers), ("--reaming-frames", frames), ("--socket-element-size", element_size))
        if value is not None
    ]
    if not given:
        return {}
    from thrsim.app.server import check_socket_element_size
    from thrsim.learn.model_dir import load_model, reads_any_mesh
    from thrsim.learn.ream import parse_reamers
    from thrsim.session.plan import REAMER_SIZES_MM

    if not reaming_page or not reads_any_mesh(load_model(model).settings):
        raise ThrsimInputError(
            f"{', '.join(given)}: a whole reaming is the reaming page's on a whole-socket model: add --reaming-page --model SOCKET_MODEL"
        )
    sizes = WHOLE_REAMING_MM if reamers is None else tuple(int(size) for size in parse_reamers(reamers))
    if reamers is not None and [float(size) for size in sizes] != parse_reamers(reamers) or not set(sizes) <= set(REAMER_SIZES_MM):
        low, high = min(REAMER_SIZES_MM), max(REAMER_SIZES_MM)
        raise ThrsimInputError(f"the page offers reamers of whole millimetres from {low} to {high}, got {reamers!r}", "reamers")
    check_socket_element_size(element_size)
    return {"reamers": sizes, "reaming_frames": frames or WHOLE_REAMING_FRAMES, "socket_element_size_mm": element_size}


def _reaming_page(model: Path | None, seconds: float, whole: dict) -> dict:
    from thrsim.app.reaming_bench import time_reaming_page
    from thrsim.learn.model_dir import load_model

    load_model(model)  # a missing or wrong model is refused here, in one line, before any browser starts
    return time_reaming_page(model, seconds, **whole)
