"""Every command offers ``--json`` (one JSON object on stdout, for scripts), found by walking the command tree's help."""

from __future__ import annotations

import json
import select
import signal
import subprocess

import typer.main
from checkout_cli import THRSIM, checkout_env

from thrsim.cli import app

#: groups that only list their commands: nothing runs, so there is nothing to print as JSON
NO_JSON = {
    (): "the root only lists the commands (and --version prints the version)",
    ("nav",): "nav only lists its commands",
    ("sessions",): "sessions only lists its commands",
    ("trackers",): "trackers only lists its commands",
}


def command_paths() -> list[tuple[str, ...]]:
    """Every command and group as the words typed after ``thrsim``, the root () first."""
    paths = []

    def walk(command, path: tuple[str, ...]) -> None:
        paths.append(path)
        for name, sub in getattr(command, "commands", {}).items():  # a group's commands
            walk(sub, (*path, name))

    walk(typer.main.get_command(app), ())
    return paths


def test_every_command_offers_json_in_its_help(thrsim_inprocess):
    paths = command_paths()
    assert {("ream",), ("bench",), ("serve",), ("report",), ("nav", "convert"), ("dataset", "pack")} <= set(paths)
    missing = []
    for path in paths:
        result = thrsim_inprocess(*path, "--help")
        assert result.returncode == 0, (path, result.stderr)
        if ("--json" in result.stdout) != (path not in NO_JSON):
            missing.append(" ".join(("thrsim", *path)))
    assert missing == [], f"--json missing (or offered by a listed exception): {missing}"
    assert set(NO_JSON) <= set(paths)  # an exception names a command that exists


def test_a_command_prints_exactly_one_json_object(thrsim_inprocess):
    result = thrsim_inprocess("nav", "convert", "--inclination", "40", "--anteversion", "15", "--json")
    assert result.returncode == 0, result.stderr
    decoder = json.JSONDecoder()
    value, end = decoder.raw_decode(result.stdout)
    assert isinstance(value, dict) and result.stdout[end:].strip() == ""


def test_serve_announces_itself_as_one_json_object(tmp_path):
    command = [*THRSIM, "serve", "--json", "--port", "0", "--igtl-port", "0", "--no-compile", "--sessions", str(tmp_path)]
    server = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=checkout_env(PYTHONUNBUFFERED="1"))
    try:
        ready, _, _ = select.select([server.stdout], [], [], 90)
        assert ready, "thrsim serve --json announced nothing in 90 s"
        announced = json.loads(server.stdout.readline())
    finally:
        server.send_signal(signal.SIGTERM)
        rest, _ = server.communicate(timeout=30)
    assert announced["url"] == f"http://127.0.0.1:{announced['port']}/" and announced["port"] > 0 and announced["igtl_port"] > 0
    assert announced["sessions"] == str(tmp_path) and rest == ""
