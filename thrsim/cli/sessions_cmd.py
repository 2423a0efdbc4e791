"""``thrsim sessions``: the trainees' record on the command line — every session's metrics exported for studies."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from thrsim.cli.output import command_group
from thrsim.errors import ThrsimInputError

app = command_group("The trainees' record: saved sessions' scores, metrics and questionnaire answers.")


@app.command("export")
def export(
    sources: list[Path] = typer.Argument(
        ..., help="session files (.h5) and folders of them (thrsim serve's sessions/)", metavar="DIR_OR_FILES..."
    ),
    as_csv: bool = typer.Option(
        False, "--csv", help="one CSV row per session: trainee, mode, date, duration, score, each metric, each answer"
    ),
    as_json: bool = typer.Option(
        False, "--json", help="one JSON object: every session's summary, the competency levels, the questionnaire items"
    ),
    out: Path | None = typer.Option(None, "--out", help="file to write (default: print)", metavar="FILE"),
    thresholds_file: Path | None = typer.Option(
        None, "--thresholds", help="competency thresholds to score against (JSON or YAML; default: the shipped ones)", metavar="FILE"
    ),
) -> None:
    """Export every session's metrics (and questionnaire answers) as CSV or JSON, oldest first."""
    if as_csv == as_json:
        raise ThrsimInputError("give --csv or --json (one of them)")
    from thrsim.report.record import session_files, summaries, to_csv, to_json
    from thrsim.report.thresholds import load_thresholds

    rows = summaries(session_files(sources), thresholds=load_thresholds(thresholds_file))
    text = to_csv(rows) if as_csv else json.dumps(to_json(rows), indent=1, allow_nan=False) + "\n"
    if out is None:
        typer.echo(text, nl=False)
        return
    from thrsim.atomic import atomic_path

    with atomic_path(out) as tmp:
        tmp.write_text(text, encoding="utf-8")
    typer.echo(f"{len(rows)} sessions written: {out}")
