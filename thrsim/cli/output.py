"""Shared output helpers for subcommands: one JSON object on stdout, rich tables otherwise."""

from __future__ import annotations

import json
import math
import reprlib
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
    "socket_element_size_mm": "--socket-element-size",
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


#: typer's usage error (a value it cannot parse, an unknown flag, a missing one): click's class, which
#: typer ≥ 0.2x vendors, so found through the BadParameter typer exports rather than imported by name
UsageError: type[Exception] = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "UsageError")

_SHOWN = reprlib.Repr()  # a refused value quoted shortly, on one line, whatever its length
_SHOWN.maxstring = 60


def describe_usage_error(error: Exception) -> str:
    """One line for a usage error of typer's, not its usage box: the flag, the problem and the value
    refused (``--frames: Input should be a valid integer, ..., got 'x' (see thrsim fem -h)``)."""
    ctx = getattr(error, "ctx", None)
    names = [] if ctx is not None else ["COMMAND"]  # no context where the parser refused (a flag without its value)
    while ctx is not None and ctx.parent is not None:  # the root's name is the program's, however it was started
        names.insert(0, ctx.info_name)
        ctx = ctx.parent
    command = " ".join(["thrsim", *names])
    param = getattr(error, "param", None)
    if type(error).__name__ == "MissingParameter" or param is None:
        text = error.format_message()  # type: ignore[attr-defined]  # click's UsageError, typed through typer's MRO
    else:
        text = f"{'/'.join(param.opts)}: {error.message}"  # type: ignore[attr-defined]
        cause = error.__cause__
        if isinstance(cause, ValidationError) and cause.errors():  # typer parsed the value with pydantic: name it
            text += f", got {_SHOWN.repr(cause.errors()[0].get('input'))}"
    return " ".join(f"{text} (see {command} -h)".split())


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
