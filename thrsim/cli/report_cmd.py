"""``thrsim report``: the assessment report of a recorded session, as one self-contained HTML file."""

from __future__ import annotations

from pathlib import Path

import typer

from thrsim.atomic import atomic_path


def report(
    session: Path = typer.Argument(..., help="session file (.h5) saved by thrsim serve"),
    out: Path = typer.Option(..., "--out", help="HTML file to write", metavar="FILE"),
) -> None:
    """Write the assessment report (plots embedded, no external files) of SESSION to --out."""
    from thrsim.report import build_report

    html = build_report(session)
    with atomic_path(out) as tmp:
        tmp.write_text(html, encoding="utf-8")
    typer.echo(f"report written: {out}")
