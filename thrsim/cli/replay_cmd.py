"""``thrsim replay``: re-live a recorded session through a fresh trainer and check it reproduces."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from thrsim.cli.output import print_json, print_table


def replay(
    session: Path = typer.Argument(..., help="session file (.h5) saved by thrsim serve"),
    model: Path | None = typer.Option(
        None,
        "--model",
        help="model folder a reaming session replays with (default: the shipped model; a session reamed with another needs this)",
        metavar="MODEL_DIR",
    ),
    json_out: bool = typer.Option(False, "--json", help="print one JSON object"),
) -> None:
    """Feed SESSION's inputs, with their times, to a fresh trainer; exit 1 if its outputs differ from the recording."""
    from thrsim.app.replay import replay_session

    outcome = replay_session(session, model=model)
    if json_out:
        print_json(outcome.as_dict())
    else:
        print_table(f"replay of {session.name}", outcome.as_dict())
    if not outcome.reproduced:
        sys.exit(1)
