"""Run this checkout's ``thrsim`` command as a user would (a subprocess), or its entry point in process."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from checkout_cli import run_thrsim


@pytest.fixture
def thrsim():
    """``thrsim(*args, cwd=...)`` → CompletedProcess with text stdout/stderr (this checkout's code)."""
    return run_thrsim


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
