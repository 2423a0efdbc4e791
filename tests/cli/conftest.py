"""Run the installed ``thrsim`` console script as a user would."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest


def _thrsim_command() -> list[str]:
    beside = Path(sys.executable).with_name("thrsim")  # the interpreter's own script, not a shim
    if beside.exists():
        return [str(beside)]
    found = shutil.which("thrsim")
    if found:
        return [found]
    return [sys.executable, "-c", "from thrsim.cli import main; main()"]


THRSIM = _thrsim_command()


@pytest.fixture
def thrsim():
    """``thrsim(*args, cwd=...)`` → CompletedProcess with text stdout/stderr."""

    def run(*args: str, cwd: Path | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
        return subprocess.run([*THRSIM, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout)

    return run


@pytest.fixture
def thrsim_inprocess(monkeypatch, capsys):
    """Run ``thrsim.cli.main`` (the console script's entry point) in this process: same error
    handling and exit codes as the installed command, without the interpreter start-up.

    ``thrsim_inprocess(*args, cwd=...)`` → CompletedProcess(returncode, stdout, stderr).
    """
    from thrsim.cli import main

    def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
        if cwd is not None:
            monkeypatch.chdir(cwd)
        monkeypatch.setattr(sys, "argv", ["thrsim", *args])
        capsys.readouterr()
        try:
            main()
            code = 0
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(["thrsim", *args], code, out, err)

    return run
