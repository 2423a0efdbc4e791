"""The suite tests this checkout: in process, and in every ``thrsim`` it starts as a subprocess,
even when another checkout's ``thrsim`` is installed or first on PATH."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

from checkout_cli import REPO_ROOT, THRSIM, checkout_env, run_thrsim

import thrsim


def test_in_process_imports_are_this_checkout():
    assert Path(thrsim.__file__).resolve().is_relative_to(REPO_ROOT / "thrsim")


def _impostor(tmp_path: Path) -> dict[str, str]:
    """An environment where another 'thrsim' shadows this one: first on PATH and on PYTHONPATH."""
    fake = tmp_path / "other-checkout"
    (fake / "thrsim").mkdir(parents=True)
    (fake / "thrsim" / "__init__.py").write_text("__version__ = 'impostor'\n")
    (fake / "thrsim" / "__main__.py").write_text("print('impostor')\n")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    script = bin_dir / "thrsim"
    script.write_text("#!/bin/sh\necho impostor\n")
    script.chmod(0o755)
    env = dict(checkout_env())
    env["PATH"] = f"{bin_dir}:{env.get('PATH', '')}"
    env["PYTHONPATH"] = str(fake)
    return env


def test_subprocess_command_runs_this_checkout_despite_another_install(tmp_path):
    env = _impostor(tmp_path)
    where = subprocess.run(
        [sys.executable, "-c", "import thrsim; print(thrsim.__file__)"],
        env=checkout_env(env),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert Path(where.stdout.strip()).resolve().is_relative_to(REPO_ROOT / "thrsim"), where
    version = run_thrsim("--version", cwd=tmp_path, env=env)
    assert (version.returncode, version.stdout.strip()) == (0, thrsim.__version__), version
    assert THRSIM[0] == sys.executable


def test_no_test_starts_a_thrsim_found_on_path():
    """Commands found on PATH (or beside the interpreter) may be another checkout's."""
    suspicious = re.compile(
        r"""shutil\.which\(\s*["']thrsim|with_name\(\s*["']thrsim|\[\s*["']thrsim["']\s*,\s*["'](?:dataset|track|verify|mesh|fem|nav|bench)"""
    )
    offenders = [
        f"{path.relative_to(REPO_ROOT)}:{number}"
        for path in sorted((REPO_ROOT / "tests").rglob("*.py"))
        if path.name != "test_checkout.py"
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if suspicious.search(line) and "argv" not in line  # sys.argv of an in-process run is fine
    ]
    assert not offenders, f"start the command with checkout_cli.THRSIM / run_thrsim instead: {offenders}"


def _subprocess_calls_without_env(path: Path) -> list[int]:
    lines = []
    for node in ast.walk(ast.parse(path.read_text())):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and isinstance(node.func.value, ast.Name)
            and node.func.value.id == "subprocess"
            and node.func.attr in ("run", "Popen", "call", "check_call", "check_output")
            and not any(k.arg == "env" for k in node.keywords)
        ):
            lines.append(node.lineno)
    return lines


def test_every_python_subprocess_gets_this_checkout_on_its_path():
    """A script or ``-c`` code started with this interpreter imports whatever thrsim its path finds."""
    offenders = [
        f"{path.relative_to(REPO_ROOT)}:{line}"
        for path in sorted((REPO_ROOT / "tests").rglob("*.py"))
        for line in _subprocess_calls_without_env(path)
    ]
    assert not offenders, f"pass env=checkout_env() (or use run_thrsim): {offenders}"
