"""``thrsim report``: the assessment report of a recorded session, as one self-contained HTML file or as data."""

from __future__ import annotations

from pathlib import Path

import typer

from thrsim.atomic import atomic_path
from thrsim.errors import ThrsimInputError


def report(
    session: Path = typer.Argument(..., help="session file (.h5) saved by thrsim serve"),
    out: Path | None = typer.Option(None, "--out", help="HTML file to write", metavar="FILE"),
    as_json: bool = typer.Option(
        False, "--json", help="print the assessment as one JSON object (score, max_score, criteria, events, metrics)"
    ),
    thresholds_file: Path | None = typer.Option(
        None, "--thresholds", help="competency thresholds to score against (JSON or YAML; default: the shipped ones)", metavar="FILE"
    ),
) -> None:
    """Write the assessment report (plots embedded, no external files) of SESSION to --out, or print it as one JSON object.

    A session where nothing was done that the trainer assesses is not scored (score and max_score null)."""
    if out is None and not as_json:
        raise ThrsimInputError("give --out FILE for the HTML report, --json for the data, or both")
    from thrsim.report.thresholds import load_thresholds

    thresholds = load_thresholds(thresholds_file)
    if out is not None:
        from thrsim.report import build_report

        html = build_report(session, thresholds)
        with atomic_path(out) as tmp:
            tmp.write_text(html, encoding="utf-8")
        if not as_json:
            typer.echo(f"report written: {out}")
    if as_json:
        from thrsim.cli.output import print_json
        from thrsim.report import build_assessment

        data = build_assessment(session, thresholds).as_json()
        print_json(data | ({"report": str(out)} if out is not None else {}))
