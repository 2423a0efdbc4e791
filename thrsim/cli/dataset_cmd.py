"""``thrsim dataset``: the resumable orientation sweep (``--out DIR ...``), ``info DIR`` and ``pack DIR --out FILE``.

Local runs use a process pool (``--workers N``); ``--scheduler tcp://HOST:PORT`` sends the
same tasks to a Dask scheduler instead. Start one and its workers with::

    dask scheduler --host 127.0.0.1 --port 8786               # or a private interface, see below
    dask worker tcp://127.0.0.1:8786 --nworkers 4 --nthreads 1

(the output directory must be visible at the same path on every worker).

"""

from __future__ import annotations

import math
import signal
import time
from pathlib import Path

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from thrsim.cli.output import check_threads, command_group, console, err_console, print_json, print_table
from thrsim.config import SocketSweepConfig, SweepConfig
from thrsim.data.executor import DASK_SECURITY
from thrsim.data.sweep import format_list
from thrsim.errors import SimulationError, ThrsimInputError

__doc__ = f"{__doc__}\n{DASK_SECURITY}"

app = command_group(
    "Generate the training dataset (an orientation sweep of the FEM solver, resumable), summarise one with `info DIR`, or reduce it to a learning pack with `pack DIR --out FILE`.",
    name="dataset",
    no_args_is_help=False,
)

_LIST_HELP = "comma list and/or start:stop:step ranges, stop included"
_SWEEP = SweepConfig()  # the sweep's defaults, defined once in thrsim.config
_SOCKET_SWEEP = SocketSweepConfig()
_SOLVER_CHOICES = ("fem", "synthetic")  # thrsim.data.generate.SOLVERS, without importing it here


@app.callback(invoke_without_command=True)
def dataset(
    ctx: typer.Context,
    out: Path | None = typer.Option(None, "--out", help="dataset directory (created; rerun to resume)", metavar="DIR"),
    bone: str = typer.Option(
        "patch",
        "--bone",
        help="patch: the orientation sweep of the thesis's patch; socket: the 0.5 plan of socket windows reamed one size up at "
        f"set feeds ({_SOCKET_SWEEP.train_cases + _SOCKET_SWEEP.validation_cases + _SOCKET_SWEEP.test_cases} cases), pushed "
        f"windows and {len(_SOCKET_SWEEP.whole_sockets) + len(_SOCKET_SWEEP.prepared_whole_sockets)} pushed whole sockets, each meshed at {format_list(_SOCKET_SWEEP.whole_socket_element_sizes_mm)} mm "
        "(the orientation and force lists do not apply)",
    ),
    inclinations: str = typer.Option(
        format_list(_SWEEP.inclinations_deg), "--inclinations", help=f"inclinations γ in degrees ({_LIST_HELP})", metavar="LIST"
    ),
    anteversions: str = typer.Option(
        format_list(_SWEEP.anteversions_deg), "--anteversions", help=f"anteversions θ in degrees ({_LIST_HELP})", metavar="LIST"
    ),
    frames: int | None = typer.Option(
        None,
        "--frames",
        help=f"output frames per case ({_SWEEP.frame_rate_hz:g} per simulated second) [default: {_SWEEP.frames} on the patch, "
        f"{_SOCKET_SWEEP.frames} on the socket]",
        metavar="N",
    ),
    forces: str = typer.Option(
        format_list(_SWEEP.forces_n), "--forces", "--force", help="push force(s) in N for the full orientation grid", metavar="LIST"
    ),
    extra_forces: str = typer.Option(
        format_list(_SWEEP.extra_forces_n),
        "--extra-forces",
        help="further push forces in N, run on the subset below only ('none' for none)",
        metavar="LIST",
    ),
    extra_force_anteversions: str = typer.Option(
        format_list(_SWEEP.extra_force_anteversions_deg),
        "--extra-force-anteversions",
        help="anteversions (every inclination) that get the extra forces",
        metavar="LIST",
    ),
    socket_plan: Path | None = typer.Option(
        None,
        "--socket-plan",
        help="JSON file of the socket plan's settings (any field of SocketSweepConfig: steps, windows, tilts, feeds, case counts, seed)",
        metavar="FILE",
    ),
    element_sizes: str | None = typer.Option(
        None, "--element-sizes", "--element-size", help="bone element size(s) in mm (default: the configured 0.45)", metavar="LIST"
    ),
    workers: int = typer.Option(1, "--workers", help="local worker processes (numerical threads are split among them)", metavar="N"),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="Dask scheduler address, e.g. tcp://127.0.0.1:8786, instead of the local pool", metavar="ADDR"
    ),
    connect_timeout: float = typer.Option(5.0, "--connect-timeout", help="seconds to reach the scheduler before giving up", metavar="S"),
    config: Path | None = typer.Option(
        None,
        "--config",
        help="JSON file of the fixed case settings (any field of ReamingCaseConfig but the swept ones, nested), e.g. a wider patch or another u_f",
        metavar="FILE",
    ),
    threads: int | None = typer.Option(
        None,
        "--threads",
        help="numerical threads per case (default: cores ÷ --workers locally, 1 per task on Dask: start more worker processes instead)",
        metavar="N",
    ),
    solver: str = typer.Option(
        "fem",
        "--solver",
        hidden=True,
        help=f"one of thrsim's own: {', '.join(_SOLVER_CHOICES)} (synthetic: the pipeline tests' stand-in, not physics)",
    ),
    except_packed: Path | None = typer.Option(
        None,
        "--except-packed",
        help="skip the cases this learning pack of the same dataset holds (a plan solved across machines or sessions: "
        "pack what is done, solve the rest, pack them into the same pack)",
        metavar="PACK",
    ),
    dry_run: bool = typer.Option(False, "--dry-run", help="print the planned cases and splits, run nothing"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Run the orientation sweep into --out DIR (skips complete cases, redoes the rest).

    Default: the grid of --inclinations × --anteversions at --forces, plus --extra-forces at
    --extra-force-anteversions (the defaults shown below); γ = 0 cases that differ only in θ are
    one physical case and run once. Split by orientation: test θ ∈ {45, 135}, validation θ = 90
    (γ > 0), the rest (and γ = 0) train.
    """
    if ctx.invoked_subcommand is not None:
        return
    from thrsim.data.generate import check_sweep_target, run_sweep, without_packed
    from thrsim.data.sweep import DEFAULT_SPLIT, SocketSplitRule, SplitRule, parse_list, plan_socket_sweep, plan_sweep

    if out is None:
        raise ThrsimInputError("thrsim dataset needs --out DIR (or the subcommand: thrsim dataset info DIR)")
    if solver not in _SOLVER_CHOICES:  # never a module named on the command line
        raise ThrsimInputError(f"--solver must be one of {', '.join(_SOLVER_CHOICES)}, got {solver!r}")
    if not 0 < connect_timeout < math.inf:
        raise ThrsimInputError(f"--connect-timeout must be a positive number of seconds, got {connect_timeout:g}")
    check_threads(workers, "--workers")  # a process each: beyond it the pool cannot start them
    check_threads(threads)
    if bone not in ("patch", "socket"):
        raise ThrsimInputError(f"--bone must be patch or socket, got {bone!r}")
    template_overrides = _template_overrides(config)
    if bone == "socket":
        if element_sizes is not None:
            raise ThrsimInputError(
                "--element-sizes applies to the patch sweep; the socket's mesh is set by socket.element_size_mm in --config"
            )
        socket_sweep = _socket_sweep(socket_plan, frames)
        plan = plan_socket_sweep(socket_sweep)
        split: SplitRule | SocketSplitRule = SocketSplitRule(socket_sweep)
        template_overrides = {**(template_overrides or {}), "bone_kind": "socket"}
    else:
        if socket_plan is not None:
            raise ThrsimInputError("--socket-plan applies to --bone socket")
        sizes = parse_list(element_sizes, "--element-sizes") if element_sizes is not None else (None,)
        plan = plan_sweep(
            parse_list(inclinations, "--inclinations"),
            parse_list(anteversions, "--anteversions"),
            frames=_SWEEP.frames if frames is None else frames,
            force_n=parse_list(forces, "--forces"),
            extra_forces_n=parse_list(extra_forces, "--extra-forces", allow_empty=True),
            extra_force_anteversions=parse_list(extra_force_anteversions, "--extra-force-anteversions", allow_empty=True),
            element_sizes_mm=sizes,
        )
        split = DEFAULT_SPLIT
    target = check_sweep_target(out, plan, solver=solver, template_overrides=template_overrides)  # what the run would refuse
    if except_packed is not None:
        plan = without_packed(plan, except_packed, target.identity)
    if dry_run:
        rows = [{**c.params(), "case_id": c.case_id, "split": split.of(c)} for c in plan.cases]
        payload = {"cases": len(plan.cases), "requested": plan.requested, "notes": plan.notes, "plan": rows}
        if as_json:
            print_json(payload)
        else:
            for note in plan.notes:
                err_console.print(f"[yellow]{note}[/yellow]")
            print_table("sweep plan", {"physical cases": len(plan.cases), "grid points asked": plan.requested})
        return

    if not plan.cases:
        if as_json:
            print_json({"out": str(out), "cases": 0, "generated": 0, "notes": plan.notes})
        else:
            err_console.print(f"every case of the plan is in {except_packed}: nothing to run", soft_wrap=True)
        return
    progress: Progress | None = None
    task = None
    state = {"frames": 0, "t0": time.perf_counter()}

    def on_start(done: int, total: int, description: str) -> None:
        nonlocal progress, task
        if not as_json:
            for note in plan.notes:
                err_console.print(f"[yellow]{note}[/yellow]")
            err_console.print(f"{total} case(s), {done} already complete; {description}")
            progress = Progress(
                SpinnerColumn(),
                TextColumn("[bold]cases"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[fps]}"),
                TimeElapsedColumn(),
                TextColumn("ETA"),
                TimeRemainingColumn(),
                console=err_console,
                transient=False,
            )
            progress.start()
            task = progress.add_task("cases", total=total, completed=done, fps="")
        state["t0"] = time.perf_counter()

    def on_event(event) -> None:
        if event.status == "complete":
            state["frames"] += event.frames
        if progress is not None and task is not None and event.status in ("complete", "failed"):
            elapsed = max(1e-9, time.perf_counter() - state["t0"])
            progress.update(task, completed=event.done, fps=f"{state['frames'] / elapsed:.2f} frames/s")
            if event.status == "complete":
                # one line per case, so a sweep logged to a file shows its progress too
                ending = f", {event.end_reason}" if event.end_reason else ""
                progress.console.print(
                    f"{event.case_id}: {event.frames} frames recorded{ending}, {event.removed:,} tets removed, "
                    f"{event.wall_s / 60:.1f} min ({event.done}/{event.total})",
                    soft_wrap=True,
                )
            if event.status == "failed":
                progress.console.print(f"[red]{event.case_id} failed: {event.message}[/red]")
        elif progress is not None and event.status == "retry":
            progress.console.print(f"[yellow]{event.case_id}: worker lost, retrying[/yellow]")

    def terminate(signum, frame) -> None:
        raise _Terminated()

    previous = signal.signal(signal.SIGTERM, terminate)  # a service manager's stop: as clean as Ctrl-C
    try:
        result = run_sweep(
            out,
            plan,
            solver=solver,
            workers=workers,
            scheduler=scheduler,
            connect_timeout_s=connect_timeout,
            threads=threads,
            on_event=on_event,
            on_start=on_start,
            template_overrides=template_overrides,
            split=split,
        )
    except KeyboardInterrupt as stop:
        if progress is not None:
            progress.stop()
        err_console.print(
            f"thrsim: stopped; every case finished so far is in {out / 'manifest.json'}: rerun the same command to go on", soft_wrap=True
        )
        raise typer.Exit(143 if isinstance(stop, _Terminated) else 130) from None
    finally:
        signal.signal(signal.SIGTERM, previous)
        if progress is not None:
            progress.stop()
    summary = result.summary()
    if as_json:
        print_json(summary)
    else:
        shown = {k: v for k, v in summary.items() if k not in ("failures", "notes")}
        print_table("dataset", shown)
    if result.failed:
        first, why = next(iter(result.failed.items()))
        raise SimulationError(f"{len(result.failed)} of {result.total} case(s) failed (first: {first}: {why}); rerun to retry them")


@app.command("info")
def info(
    directory: Path = typer.Argument(..., help="dataset directory", metavar="DIR"),
    plot: Path | None = typer.Option(
        None, "--plot", help="write the α histograms of removed vs remaining elements (Figure 44) to this PNG", metavar="PNG"
    ),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Summarise a dataset: cases, frames, splits, removed fraction per frame, PEEQ/von Mises ranges."""
    from thrsim.data.info import dataset_info, plot_alpha_histograms

    if plot is not None and plot.suffix.lower() != ".png":
        raise ThrsimInputError(f"{plot}: --plot writes a PNG; give a .png name")
    summary = dataset_info(directory, histograms=plot is not None)
    if plot is not None:
        plot_alpha_histograms(summary, plot)
        summary["plot"] = str(plot)
        summary.pop("alpha_histogram", None)
    if as_json:
        print_json(summary)
        return
    per_frame = summary.pop("removed_fraction_per_frame")
    rates = summary.pop("solver_rates")
    calibration = summary.pop("socket_calibration", None) or {}
    rows = {k: v for k, v in summary.items() if k not in ("split_rule",)}
    if calibration.get("seated"):
        seated = calibration["seated"]
        rows["seated feed at a set-feed reaction"] = ", ".join(f"{push} N: {v['feed_mm_s']:.2f} mm/s" for push, v in seated.items())
    if "pushed" in calibration:
        pushed = calibration["pushed"]
        rows["cutting threshold by polar band"] = ", ".join(
            f"{b['polar_deg']:g}°: {b['bracket_n_mm2'][0]:.2f}–{b['bracket_n_mm2'][1]:.2f} N/mm²" for b in pushed["bands"]
        )
        rows["seated push to cut"] = ", ".join(
            f"{size} mm: {low:.0f}–{high:.0f} N" for size, (low, high) in pushed["seated_push_n"].items()
        )
    for key, group in rates.items():
        gamma, force = key.split("/")
        figures = [f"{group['cases']} case(s)", ", ".join(f"{n} {end}" for end, n in group["end_reasons"].items())]
        if group["feed_rate_mm_s"] is not None:
            figures.append(f"feed {group['feed_rate_mm_s']:.2f} mm/s, removal {group['removal_rate_mm3_s']:.0f} mm³/s (medians)")
        figures.append(f"{group['worker_hours']:.2f} worker h")
        rows[f"γ {gamma}°, {force} N"] = "; ".join(figures)
    if per_frame:
        rows["removed fraction, last frame"] = per_frame[-1]
        step = max(1, len(per_frame) // 8)
        rows["removed fraction per frame (sampled)"] = ", ".join(f"{t}:{per_frame[t]:.3f}" for t in range(0, len(per_frame), step))
    print_table(f"dataset {directory}", rows)
    if plot is not None:
        console.print(f"α histograms written to {plot}")


@app.command("pack")
def pack(
    directory: Path = typer.Argument(..., help="dataset directory", metavar="DIR"),
    out: Path = typer.Option(
        ...,
        "--out",
        help="learning pack to write: one FILE.h5, or a FOLDER of files of at most --shard-mb each (an existing pack of the same dataset keeps its cases and gains these)",
        metavar="FILE.h5|FOLDER",
    ),
    shard_mb: float = typer.Option(15.0, "--shard-mb", min=1.0, help="largest size of one file of a pack folder", metavar="MB"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Reduce a dataset's complete cases to what the learned simulator reads (α, removals, reamer path) in one small file or a folder of them."""
    from thrsim.data.pack import write_pack

    summary = write_pack(directory, out, shard_mb=shard_mb)
    if as_json:
        print_json(summary)
        return
    print_table(
        f"learning pack {out}",
        {
            **summary,
            "added": ", ".join(summary["added"]) or "none",
            **({"files": ", ".join(summary["files"])} if "files" in summary else {}),
        },
    )


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C would be so that the sweep stops as cleanly (exit 143, not 130)."""


_SWEPT = ("inclination_deg", "anteversion_deg", "force_n", "frames")


def _socket_sweep(plan_file: Path | None, frames: int | None) -> SocketSweepConfig:
    """The socket plan: the defaults, a --socket-plan file's settings over them, --frames over both."""
    from pydantic import ValidationError

    from thrsim.config import read_settings_file

    settings = {} if plan_file is None else read_settings_file(str(plan_file))
    if frames is not None:
        settings["frames"] = frames
    try:
        return SocketSweepConfig(**settings)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"]) or "the plan"
        raise ThrsimInputError(f"{plan_file or '--frames'}: {where}: {first['msg']}") from None


def _template_overrides(config: Path | None) -> dict | None:
    """The --config file's settings for every case, refusing the ones the sweep's own flags set."""
    if config is None:
        return None
    from thrsim.config import read_settings_file
    from thrsim.data.generate import template_of

    settings = read_settings_file(str(config))
    swept = [key for key in _SWEPT if key in settings]
    if swept:
        raise ThrsimInputError(f"{config}: {', '.join(swept)} are set by the sweep's own flags, not by --config")
    template_of(1, settings)  # bad values fail here, before anything is run or written
    return settings
