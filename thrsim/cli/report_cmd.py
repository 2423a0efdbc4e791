"""``thrsim report``: the assessment report of a recorded session, as one self-contained HTML file."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import typer

from thrsim.atomic import atomic_path
from thrsim.cli.output import print_json


def report(
    session: Path = typer.Argument(..., help="session file (.h5) saved by thrsim serve"),
    out: Path = typer.Option(..., "--out", help="HTML file to write", metavar="FILE"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout: the report's path, score and criteria"),
) -> None:
    """Write the assessment report (plots embedded, no external files) of SESSION to --out."""
    from thrsim.report import assess

    assessment = assess(session)
    with atomic_path(out) as tmp:
        tmp.write_text(assessment.html, encoding="utf-8")
    if as_json:
        print_json(
            {
                "report": str(out),
                "session": str(session),
                "score": assessment.score,
                "max_score": assessment.max_score,
                "criteria": [asdict(c) for c in assessment.criteria],
            }
        )
    else:
        typer.echo(f"report written: {out}")
