"""``thrsim trackers``: the tracker set-ups labs run, ready to use (PlusServer device sets)."""

from __future__ import annotations

from pathlib import Path

import typer

from thrsim.cli.output import command_group, print_json

app = command_group("Tracker set-ups: PlusServer configurations that stream the device names thrsim reads.")


@app.command("plus")
def plus(
    tracker: str = typer.Option(..., "--tracker", help="the optical tracker: ndi (Polaris, Vega) or optitrack (Motive)"),
    out: Path | None = typer.Option(None, "--out", help="file to write the configuration to (default: print it)", metavar="FILE"),
    as_json: bool = typer.Option(
        False, "--json", help="one JSON object: the device set's name, port, tools and the transform (device) names it streams"
    ),
) -> None:
    """Print (or write) the PlusServer device set for a tracker: its OpenIGTLink server streams the
    TRANSFORM names thrsim reads, on OpenIGTLink's port."""
    from thrsim.io.plus import describe, device_set

    text = device_set(tracker)
    if out is not None:
        from thrsim.atomic import atomic_path

        with atomic_path(out) as tmp:
            tmp.write_text(text, encoding="utf-8")
    if as_json:
        print_json({**describe(tracker), "file": None if out is None else str(out)})
    elif out is None:
        typer.echo(text, nl=False)
    else:
        typer.echo(f"PlusServer device set for {tracker} written: {out}")
