"""``thrsim evaluate``: Table-10-style scores of a model on a dataset's held-out split or one case file."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from thrsim.cli.output import check_threads, console, err_console, print_json
from thrsim.errors import ThrsimInputError


def _pct(value) -> str:
    return "–" if value is None else f"{100 * value:.1f}"


def evaluate(
    data: Path = typer.Option(
        ..., "--data", help="dataset directory (its test split unless --split) or one case file", metavar="DIR_OR_CASE"
    ),
    model: Path | None = typer.Option(
        None, "--model", help="model directory (default: the shipped model of the data's bone: patch or socket)", metavar="MODEL_DIR"
    ),
    split: str = typer.Option("test", "--split", help="split of a dataset directory to score: test, validation, train or all"),
    start_stride: int = typer.Option(30, "--start-stride", help="frames between the start frames of the rollout windows", metavar="N"),
    one_step_stride: int = typer.Option(
        1, "--one-step-stride", help="frames between the start frames of the one-step (t+1) windows", metavar="N"
    ),
    per_case: bool = typer.Option(
        False, "--per-case", help="instead of windows, each case from its first frame to its last, one row per case"
    ),
    threads: int = typer.Option(1, "--threads", help="PyTorch threads", metavar="N"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Roll the model out from ground-truth frames and score newly removed elements at t+1, t+30, t+60 (and to a case's end)."""
    if split not in ("test", "validation", "train", "all"):
        raise ThrsimInputError(f"--split must be test, validation, train or all, got {split!r}")
    for name, stride in (("--start-stride", start_stride), ("--one-step-stride", one_step_stride)):
        if stride < 1:
            raise ThrsimInputError(f"{name} must be at least 1, got {stride}")
    check_threads(threads)
    import torch

    from thrsim.data.pack import is_pack
    from thrsim.learn.cases import load_cases
    from thrsim.learn.evaluation import case_scores
    from thrsim.learn.evaluation import evaluate as run_evaluation
    from thrsim.learn.model_dir import load_model, shipped_model_for

    torch.set_num_threads(threads)
    splits = None if split == "all" or (data.is_file() and not is_pack(data)) else (split,)
    mesh, cases = load_cases(data, splits=splits, one_mesh=False)
    loaded = load_model(shipped_model_for(cases) if model is None else model, expect_mesh=mesh)
    on_case = None if as_json else lambda i, n, c: err_console.print(f"{c} ({i}/{n})")
    if per_case:
        rows = case_scores(loaded, cases, on_case)
        if as_json:
            print_json(
                {"cases": rows, "model": {"path": str(loaded.path)}, "data": {"source": str(data), "split": split if splits else "all"}}
            )
        else:
            print_case_scores(rows)
        return
    report = run_evaluation(
        loaded,
        cases,
        start_stride=start_stride,
        one_step_stride=one_step_stride,
        on_case=on_case,
    )
    report["model"] = {"path": str(loaded.path), "arch": loaded.card.get("arch"), "data_digest": loaded.card["data"]["digest"]}
    report["data"] = {"source": str(data), "split": split if splits else "all"}
    if as_json:
        print_json(report)
        return
    print_comparison(report)


def print_case_scores(rows: list[dict]) -> None:
    """One row per case and mode: F1 %, volume error %, surface mm, diameter, depth (the deepest removed element's and
    the fitted sphere's) and reamer end against the solver's (mm);
    tool-forced, the plate left ahead of the teeth at the last frame beside the solver's (mm³)."""
    table = Table(title="each case from its first frame to its last, against the solver")
    columns = (
        "case",
        "split",
        "model",
        "F1 %",
        "volume %",
        "surface mm",
        "diameter mm",
        "depth mm",
        "sphere depth mm",
        "reamer end mm",
        "plate left mm³ (solver)",
    )
    for column in columns:
        table.add_column(column)
    names = {"autonomous": "GN autonomous", "tool_forced": "GN tool-forced", "mlp": "MLP", "geometric": "geometric"}

    def cell(value, scale: float = 1.0, digits: int = 2) -> str:
        return "–" if value is None else f"{scale * value:+.{digits}f}"

    for row in rows:
        for mode, name in names.items():
            if mode not in row:
                continue
            s = row[mode]
            table.add_row(
                row["case_id"],
                row["split"] or "–",
                name,
                _pct(s["f1"]),
                cell(s["removed_volume_error"], 100.0, 1),
                "–" if s["surface_distance_mean_mm"] is None else f"{s['surface_distance_mean_mm']:.3f}",
                cell(s["cavity_diameter_error_mm"]),
                cell(s["cavity_depth_error_mm"]),
                cell(s["sphere_depth_error_mm"]),
                cell(s["reamer_end_error_mm"]),
                f"{s['plate_left_mm3'][-1]:.0f} ({s['solver_plate_left_mm3'][-1]:.0f})" if "plate_left_mm3" in s else "",
            )
    Console(width=max(console.width, 175)).print(table)


def print_comparison(report: dict) -> None:
    """Rows γ (a socket model: reamer size) × model; columns P / R / F1 per horizon, beside the thesis's Table 10."""
    by_size = report.get("rows") == "reamer_diameter_mm"
    table = Table(title=f"removed elements on held-out {'cases' if by_size else 'orientations'}, % (P / R / F1; n = windows)")
    table.add_column("reamer mm" if by_size else "γ")
    table.add_column("model")
    horizons = ("1", "30", "60", "end")
    for h in horizons:
        table.add_column(f"t+{h}" if h != "end" else "to end")
    table.add_column("surface mean mm")
    table.add_column("depth error mm")
    table.add_column("diameter error mm")
    sources = (report, report["tool_forced"], report["mlp"], report["geometric"])
    gammas = sorted({g for source in sources for g in source if g.replace(".", "", 1).isdigit()}, key=float)
    thesis = {} if by_size else report["thesis_table_10_percent"]
    for g in gammas:
        for name, source in (
            ("GN autonomous", report),
            ("GN tool-forced", report["tool_forced"]),
            ("MLP", report["mlp"]),
            ("geometric", report["geometric"]),
        ):
            row = source.get(g, {})
            cells = []
            for h in horizons:
                c = row.get(h)
                cells.append("" if c is None else f"{_pct(c['precision'])} / {_pct(c['recall'])} / {_pct(c['f1'])} (n={c['windows']})")
            longest = row.get("longest_horizon", {})
            surface, depth, diameter = (
                longest.get(key) for key in ("surface_distance_mean_mm", "cavity_depth_error_mean_mm", "cavity_diameter_error_mean_mm")
            )
            table.add_row(
                g,
                name,
                *cells,
                "" if surface is None else f"{surface:.3f}",
                "" if depth is None else f"{depth:.2f}",
                "" if diameter is None else f"{diameter:.2f}",
            )
        if g in thesis:
            cells = [("" if h not in thesis[g] else " / ".join(f"{v:.1f}" for v in thesis[g][h].values())) for h in horizons]
            table.add_row(g, "thesis Table 10", *cells, "", "", "")
    # wide enough for P / R / F1 cells of four horizons, also when piped to a file
    Console(width=max(console.width, 170)).print(table)
    names = {"autonomous": "GN autonomous", "tool_forced": "GN tool-forced", "mlp": "MLP", "geometric": "geometric"}
    for mode, layers in report.get("by_layer", {}).items():
        if len(layers) > 1:
            layer_cells = ", ".join(f"{layer} {_pct(c['f1'])}" for layer, c in layers.items())
            console.print(f"{names[mode]}, F1 by bone layer at each window's longest horizon, %: {layer_cells}")
    for mode, controls in report.get("by_control", {}).items():
        if len(controls) > 1:
            control_cells = ", ".join(
                f"{name} {_pct(c['end']['f1'])}"
                + ("" if c["cavity_depth_error_mean_mm"] is None else f" (depth error {c['cavity_depth_error_mean_mm']:.2f} mm)")
                for name, c in controls.items()
            )
            console.print(f"{names[mode]}, F1 to the end by how the solver drove the reamer, %: {control_cells}")
    checks = report.get("physics_checks", {})
    if checks.get("checked"):
        held = ", ".join(f"{name.replace('_', ' ')} {count}/{checks['cases']}" for name, count in checks["held"].items())
        volumes = ", ".join(f"{share}× {volume:.1f}" for share, volume in checks["removed_volume_mm3_mean_by_push_share"].items())
        console.print(f"physics checks over {checks['frames']} frames (cases that hold): {held}; mean removed mm³ by push share: {volumes}")
    elif checks:
        console.print(f"physics checks: not run ({checks['why']})")
    reaction_rows = [(f"reamer {size} mm", errors) for size, errors in report.get("reaction", {}).items()]
    reaction_rows += [(bone, errors) for bone, errors in report.get("reaction_by_bone", {}).items()]
    for name, errors in reaction_rows:
        force, torque = errors["force_error"], errors["torque_error"]
        line = f"{name}: the law at the solver's feeds: reaction error {_pct(force)} %, motor torque {_pct(torque)} %"
        if errors["pushed_cases"]:
            line += (
                f"; felt under the push ({errors['pushed_cases']} pushed cases): reaction {_pct(errors['felt_force_error'])} %,"
                f" torque {_pct(errors['felt_torque_error'])} % per frame, {_pct(errors['felt_force_step_mean_error'])} % and"
                f" {_pct(errors['felt_torque_step_mean_error'])} % of the step's mean"
                f"; the feed the push balances at the solver's states {_pct(errors['balanced_feed_share'])} % of the solver's"
                f" ({_pct(errors['seated_balanced_feed_share'])} % over each case's second half)"
            )
        console.print(line + " (errors Σ|error| / Σ|solver's|)")
