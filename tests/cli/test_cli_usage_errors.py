"""Every flag of every command, walked from the typer app's own registry (a new command or flag is
covered without touching this file): a value typer cannot parse, a flag without its value and a
flag the command does not know are one line on stderr naming the flag and the value, exit 2,
nothing written, never typer's multi-line usage box (issue 27, item 5)."""

from __future__ import annotations

import inspect
import types
import typing
from pathlib import Path

import pytest
import typer
from test_cli_errors import assert_one_line_error

from thrsim.cli import app


def _commands(group: typer.Typer, path: tuple[str, ...] = ()):
    """(command path, its function) for every command and group callback registered on ``group``."""
    if group.registered_callback is not None and group.registered_callback.callback is not None:
        yield path, group.registered_callback.callback
    for command in group.registered_commands:
        yield (*path, command.name or command.callback.__name__), command.callback
    for sub in group.registered_groups:
        yield from _commands(sub.typer_instance, (*path, sub.name))


def _bare(annotation):
    """``int`` for ``int | None``, ``Optional[int]`` or ``int``; the annotation itself otherwise."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        rest = [a for a in typing.get_args(annotation) if a is not type(None)]
        return rest[0] if len(rest) == 1 else annotation
    return annotation


def _options() -> list[tuple[tuple[str, ...], str, object]]:
    """(command path, flag, bare type) of every option that takes a value."""
    found = []
    for path, function in _commands(app):
        hints = typing.get_type_hints(function)
        for name, parameter in inspect.signature(function).parameters.items():
            declared = getattr(parameter.default, "param_decls", None)
            kind = _bare(hints.get(name))
            if isinstance(parameter.default, typer.models.OptionInfo) and declared and kind is not bool:
                found.append((path, declared[0], kind))
    return found


OPTIONS = _options()
NUMERIC = [(path, flag, kind) for path, flag, kind in OPTIONS if kind in (int, float)]
#: a value typer refuses for each numeric type: not a number, a fraction for an integer, an empty value
NOT_PARSED = {int: ("x", "1.5", ""), float: ("x", "1,5", "")}


def _label(path, flag, value=None) -> str:
    return " ".join((*path, flag, *(() if value is None else (repr(value),))))


def test_the_walk_finds_the_commands_numeric_options():
    """The walk reaches subcommands, group callbacks and nested groups: it cannot pass by finding nothing."""
    found = {(" ".join(path), flag) for path, flag, _ in NUMERIC}
    expected = {("fem", "--frames"), ("fem", "--effective-mass"), ("serve", "--port"), ("dataset", "--workers")}
    expected |= {("dataset pack", "--shard-mb"), ("nav convert", "--inclination"), ("ream", "--force"), ("track", "--idle-timeout")}
    assert expected <= found, expected - found
    assert (("fem",), "--out", Path) in OPTIONS and all(kind is not bool for _, _, kind in OPTIONS)


@pytest.mark.parametrize(
    ("path", "flag", "value"),
    [(path, flag, value) for path, flag, kind in NUMERIC for value in NOT_PARSED[kind]],
    ids=[_label(path, flag, value) for path, flag, kind in NUMERIC for value in NOT_PARSED[kind]],
)
def test_a_value_that_is_not_a_number_is_one_line(thrsim_inprocess, tmp_path, path, flag, value):
    """``thrsim fem --frames x``, ``thrsim serve --port abc``: refused by the flag's type, before any
    work, in one line naming the flag, the value and the command's help."""
    line = assert_one_line_error(thrsim_inprocess(*path, flag, value, cwd=tmp_path), flag, repr(value))
    assert f"see {' '.join(('thrsim', *path))} -h" in line
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("path", "flag"), [(p, f) for p, f, _ in OPTIONS], ids=[_label(p, f) for p, f, _ in OPTIONS])
def test_a_flag_without_its_value_is_one_line(thrsim_inprocess, tmp_path, path, flag):
    assert_one_line_error(thrsim_inprocess(*path, flag, cwd=tmp_path), flag, "requires an argument")
    assert list(tmp_path.iterdir()) == []


COMMANDS = sorted({path for path, _ in _commands(app) if path})


@pytest.mark.parametrize("path", COMMANDS, ids=[" ".join(p) for p in COMMANDS])
def test_an_unknown_flag_is_one_line(thrsim_inprocess, tmp_path, path):
    assert_one_line_error(thrsim_inprocess(*path, "--no-such-flag", "1", cwd=tmp_path), "No such option: --no-such-flag")
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_command_is_one_line(thrsim_inprocess, tmp_path):
    assert_one_line_error(thrsim_inprocess("no-such-command", cwd=tmp_path), "no-such-command", "see thrsim -h")
