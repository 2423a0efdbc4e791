"""The ``thrsim`` command: one typer app, each subcommand in its own module of this package.

Every subcommand module exposes a function that is registered here; errors of the user's
making (:class:`ThrsimInputError`, pydantic validation, a flag typer cannot parse or does not
know) and any ``OSError`` the system raises on a path (a file in the way, no permission, a full
disk) become one line on stderr and exit 2.
"""

from __future__ import annotations

import sys

import typer
from pydantic import ValidationError

from thrsim import __version__
from thrsim.cli import (
    bench_cmd,
    dataset_cmd,
    evaluate_cmd,
    fem_cmd,
    mesh_cmd,
    nav_cmd,
    ream_cmd,
    replay_cmd,
    report_cmd,
    review_cmd,
    serve_cmd,
    sessions_cmd,
    track_cmd,
    trackers_cmd,
    train_cmd,
    verify_cmd,
)
from thrsim.cli.output import UsageError, command_group, describe_os_error, describe_usage_error, format_validation_error, user_message
from thrsim.errors import SimulationError, ThrsimInputError

app = command_group("Physically-based and learned simulation of acetabular reaming (total hip replacement training).", name="thrsim")


def _print_version(value: bool) -> None:
    # runs while the options are parsed, so `thrsim --version` needs no subcommand
    if value:
        typer.echo(__version__)
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", help="print the thrsim version and exit", is_eager=True, callback=_print_version),
) -> None:
    """Physically-based and learned simulation of acetabular reaming (total hip replacement training)."""


app.command("mesh")(mesh_cmd.mesh)
app.command("fem")(fem_cmd.fem)
app.command("bench")(bench_cmd.bench)
app.command("track")(track_cmd.track)
app.command("verify")(verify_cmd.verify)
app.command("serve")(serve_cmd.serve)
app.command("report")(report_cmd.report)
app.command("replay")(replay_cmd.replay)
app.command("review")(review_cmd.review)
app.command("train")(train_cmd.train)
app.command("evaluate")(evaluate_cmd.evaluate)
app.command("ream")(ream_cmd.ream)
app.add_typer(nav_cmd.app, name="nav")
app.add_typer(dataset_cmd.app, name="dataset")
app.add_typer(sessions_cmd.app, name="sessions")
app.add_typer(trackers_cmd.app, name="trackers")


def main() -> None:
    """Entry point of the ``thrsim`` console script."""
    try:
        code = app(standalone_mode=False)  # typer returns, not exits: its usage errors reach the handlers below
    except UsageError as error:
        if type(error).__name__ != "NoArgsIsHelpError":  # a bare `thrsim` or `thrsim nav`: typer printed the help
            typer.echo(f"thrsim: error: {describe_usage_error(error)}", err=True)
        sys.exit(2)
    except typer.Abort:
        typer.echo("thrsim: aborted", err=True)
        sys.exit(1)
    except ThrsimInputError as error:
        typer.echo(f"thrsim: error: {user_message(error)}", err=True)
        sys.exit(2)
    except ValidationError as error:
        typer.echo(f"thrsim: error: {format_validation_error(error)}", err=True)
        sys.exit(2)
    except SimulationError as error:
        typer.echo(f"thrsim: simulation stopped: {error}", err=True)
        sys.exit(3)
    except OSError as error:  # a path the system refuses (exists, permission, disk full): still one line
        typer.echo(f"thrsim: error: {describe_os_error(error)}", err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        typer.echo("thrsim: interrupted", err=True)
        sys.exit(130)
    sys.exit(code if isinstance(code, int) else 0)  # typer.Exit's code (a stopped sweep, a failed check), else success
