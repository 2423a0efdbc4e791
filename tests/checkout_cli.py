"""Run *this checkout's* ``thrsim`` as a subprocess, never whichever ``thrsim`` is on PATH.

A ``thrsim`` console script (on PATH, or beside the interpreter) belongs to whatever checkout was
last installed, so a test that starts it can pass while this checkout is broken. Every test that
starts the command uses :data:`THRSIM` (this interpreter, ``-m thrsim``) with :func:`checkout_env`
(this repository's root first on ``PYTHONPATH``, so it wins over any installed copy, whatever the
working directory). Processes that import thrsim themselves (Dask workers) get the same env.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
THRSIM = [sys.executable, "-m", "thrsim"]


def checkout_env(base: dict[str, str] | None = None, **extra: str) -> dict[str, str]:
    """``base`` (default: this process's environment) with the repository root first on PYTHONPATH."""
    env = dict(os.environ if base is None else base)
    rest = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and Path(p).resolve() != REPO_ROOT]
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT), *rest])
    env.update(extra)
    return env


def run_thrsim(*args: str, cwd: Path | None = None, timeout: float = 120, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``thrsim ARGS`` from this checkout → CompletedProcess with text stdout/stderr."""
    return subprocess.run([*THRSIM, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, env=checkout_env(env))


def run_main(monkeypatch, capsys, *args: str) -> tuple[int, str, str]:
    """This checkout's ``thrsim.cli.main`` in process (the console script's entry point, same exit
    codes and one-line errors, without an interpreter start-up): (exit code, stdout, stderr)."""
    from thrsim.cli import main

    monkeypatch.setattr(sys, "argv", ["thrsim", *args])
    capsys.readouterr()
    code = 0
    try:
        main()
    except SystemExit as exit_:
        code = exit_.code or 0
    out, err = capsys.readouterr()
    return code, out, err
