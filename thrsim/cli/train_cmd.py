"""``thrsim train``: the Graph Network, the MLP baseline and the reamer-advance regressor from a dataset."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from thrsim.cli.output import check_threads, err_console, print_json, print_table
from thrsim.errors import ThrsimInputError


def train(
    data: Path = typer.Option(..., "--data", help="dataset directory written by `thrsim dataset` (uses its splits)", metavar="DIR"),
    out: Path = typer.Option(..., "--out", help="model directory to write (resumes its checkpoint if interrupted)", metavar="MODEL_DIR"),
    arch: str = typer.Option(
        "production", "--arch", help="production (sized for an interactive CPU step) or thesis (the thesis's sizes and features)"
    ),
    epochs: int | None = typer.Option(None, "--epochs", help="training epochs (default 30)", metavar="N"),
    samples_per_epoch: int | None = typer.Option(
        None, "--samples-per-epoch", help="frame pairs drawn per epoch (default: all)", metavar="N"
    ),
    max_minutes: float | None = typer.Option(
        None, "--max-minutes", help="stop after the epoch that crosses this time budget", metavar="MIN"
    ),
    seed: int | None = typer.Option(None, "--seed", help="random seed (default 0)"),
    settings_file: Path | None = typer.Option(
        None, "--settings", help="JSON of settings (arch / features / train sections, nested) over the --arch preset", metavar="FILE"
    ),
    threads: int = typer.Option(1, "--threads", help="PyTorch threads", metavar="N"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace a finished model in MODEL_DIR"),
    init_from: Path | None = typer.Option(
        None,
        "--init-from",
        help="start from the networks of this trained model (same architecture and mesh) instead of fresh weights",
        metavar="MODEL_DIR",
    ),
    advance_only: bool = typer.Option(
        False, "--advance-only", help="refit only the reamer regressor of the trained model in MODEL_DIR, on the data it was trained on"
    ),
    advance_kind: str | None = typer.Option(
        None,
        "--advance-kind",
        help="the reamer regressor to keep: svr (the default setting), random_forest, ridge, linear, or lowest_cv "
        "(the lowest cross-validated error of one frame's advance)",
        metavar="KIND",
    ),
    as_json: bool = typer.Option(False, "--json", help="print the model card as one JSON object on stdout"),
) -> None:
    """Train the learned simulator on a dataset's training split; write weights, regressor, mesh and card."""
    from thrsim.learn.settings import ModelSettings, preset_with_file

    check_threads(threads)
    settings = preset_with_file(arch, None if settings_file is None else str(settings_file))
    for key, value in (("epochs", epochs), ("max_samples_per_epoch", samples_per_epoch), ("max_minutes", max_minutes), ("seed", seed)):
        if value is not None:
            settings["train"][key] = value
    if advance_kind is not None:
        from thrsim.learn.advance import KINDS, LOWEST_CV

        if advance_kind not in (*KINDS, LOWEST_CV):
            raise ThrsimInputError(f"--advance-kind must be one of {', '.join((*KINDS, LOWEST_CV))}, got {advance_kind!r}")
        settings["train"]["advance_kind"] = advance_kind
    model_settings = ModelSettings.model_validate(settings)
    if advance_only:
        from thrsim.learn.pipeline import refit_advance

        card = refit_advance(data, out, advance_kind)
        if as_json:
            print_json(card)
        else:
            _print_advance(card)
        return

    import torch
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from thrsim.learn.pipeline import train_model

    torch.set_num_threads(threads)
    # the bar starts once the data are read and checked, so a refused run prints one line only
    progress = Progress(
        TextColumn("[bold]epoch {task.fields[epoch]}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[note]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        disable=as_json,
    )
    task = progress.add_task("train", total=None, epoch="-", note="", start=False)

    started: list[bool] = []

    def on_start(info: dict) -> None:
        if not as_json:
            resumed = f", resuming after epoch {info['resumed_at_epoch']}" if info["resumed_at_epoch"] is not None else ""
            err_console.print(
                f"{info['train_cases']} training case(s), {info['validation_cases']} validation, {info['pairs']} frame pairs, {info['elements']} elements{resumed}"
            )
            progress.start()
            progress.start_task(task)
            started.append(True)

    def on_batch(done: int, total: int) -> None:
        progress.update(task, total=total, completed=done)

    def on_epoch(report) -> None:
        f1 = "n/a" if report.validation_f1 is None else f"{report.validation_f1:.3f}"
        note = f"loss {report.gn_loss:.4f} (mlp {report.mlp_loss:.4f}), validation F1 {f1}"
        progress.update(task, epoch=f"{report.epoch}/{report.epochs}", note=note)
        if not as_json:
            progress.console.print(f"epoch {report.epoch}/{report.epochs}: {note}, {report.seconds:.1f} s")

    try:
        card = train_model(
            data,
            out,
            model_settings,
            arch,
            overwrite=overwrite,
            init_from=init_from,
            on_start=on_start,
            on_epoch=on_epoch,
            on_batch=on_batch,
        )
    finally:
        if started:
            progress.stop()
    if as_json:
        print_json(card)
        return
    advance = card["advance"]
    print_table(
        f"model written to {out}",
        {
            "epochs": card["training"]["epochs"],
            "training time (s)": card["training"]["network_seconds"] + card["training"]["advance_seconds"],
            "final loss": card["metrics"]["final_gn_loss"],
            "validation F1": card["metrics"]["validation_f1"] if card["metrics"]["validation_f1"] is not None else "n/a",
            "advance regressor": advance["chosen"],
        },
    )
    _print_advance(card)


def _print_advance(card: dict) -> None:
    advance = card["advance"]
    err_console.print(
        f"advance regressor ({advance['chosen']} chosen; mm per frame): "
        + json.dumps({k: {kk: vv for kk, vv in v.items() if kk != "best_params"} for k, v in advance["models"].items()})
    )
