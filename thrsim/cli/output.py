"""Shared output helpers for subcommands: one JSON object on stdout, rich tables otherwise."""

from __future__ import annotations

import json
import math
from typing import Any

import typer
from pydantic import ValidationError
from rich.console import Console
from rich.table import Table

from thrsim.errors import ThrsimInputError, ThrsimOutputError
from thrsim.provenance import json_default

console = Console()
err_console = Console(stderr=True)


def print_json(payload: dict) -> None:
    """Print exactly one JSON object on stdout (non-finite floats become null)."""

    def clean(value: Any) -> Any:
        if isinstance(value, float) and not math.isfinite(value):
            return None
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        return value

    print(json.dumps(clean(payload), default=json_default, indent=2))


def print_table(title: str, rows: dict[str, Any]) -> None:
    """A two-column rich table of named figures."""
    table = Table(title=title, show_header=False)
    table.add_column("figure", style="bold")
    table.add_column("value")
    for key, value in rows.items():
        table.add_row(key, f"{value:.6g}" if isinstance(value, float) else str(value))
    console.print(table)


#: settings whose flag is not ``--`` and the name with ``-`` for ``_``
FLAGS = {
    "inclination_deg": "--inclination",
    "anteversion_deg": "--anteversion",
    "model_dir": "--model",
    "sessions_dir": "--sessions",
    "token": "--token-file or THRSIM_TOKEN",
}


def flag_of(setting: str) -> str:
    """The command-line flag that sets a library setting (``igtl_allow`` → ``--igtl-allow``)."""
    return FLAGS.get(setting, "--" + setting.replace("_", "-"))


def user_message(error: ThrsimInputError) -> str:
    """A library error worded for the command line: the settings it names as their flags."""
    text = error.message
    for name in error.mentions:
        text = text.replace(f"({name})", f"({flag_of(name)})")
    return text if error.setting is None else f"{flag_of(error.setting)}: {text}"


def format_validation_error(error: ValidationError) -> str:
    """pydantic's multi-line report folded into one line: 'field: problem; field: problem'."""
    parts = []
    for item in error.errors():
        where = ".".join(str(p) for p in item.get("loc", ())) or error.title
        parts.append(f"{where}: {item.get('msg', 'invalid')}")
    return "invalid configuration: " + "; ".join(parts)


def describe_os_error(error: OSError) -> str:
    """'<file>: <problem>' for an OSError (both files for a rename), on one line."""
    if isinstance(error, ThrsimOutputError):  # it names the output, not its temporary file
        return str(error)
    problem = error.strerror or str(error) or type(error).__name__
    if error.filename is not None and error.filename2 is not None:
        return f"{error.filename} -> {error.filename2}: {problem}"
    if error.filename is not None:
        return f"{error.filename}: {problem}"
    return " ".join(problem.split())


#: more threads than any machine thrsim runs on has cores; beyond it PyTorch overflows or the OS refuses
MAX_THREADS = 4096


def check_threads(threads: int | None, flag: str = "--threads") -> None:
    """Refuse a thread count below 1 or above :data:`MAX_THREADS` in one line (None: the default)."""
    if threads is not None and not 1 <= threads <= MAX_THREADS:
        raise ThrsimInputError(f"{flag} must lie in 1..{MAX_THREADS}, got {threads}")


def command_group(help: str, name: str | None = None, no_args_is_help: bool = True) -> typer.Typer:
    """A typer app with thrsim's conventions: -h/--help, no completion install, no pretty tracebacks."""
    return typer.Typer(
        name=name,
        help=help,
        no_args_is_help=no_args_is_help,
        add_completion=False,
        pretty_exceptions_enable=False,
        context_settings={"help_option_names": ["-h", "--help"]},
    )
