"""The checkout passes ruff's lint and format checks (pyproject.toml's rules), as `.ci/run` asks:
a local test run catches what CI would."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from checkout_cli import REPO_ROOT, checkout_env

RUFF = [sys.executable, "-m", "ruff"]


def _ruff(*args: str, cwd: Path = REPO_ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([*RUFF, *args], cwd=cwd, capture_output=True, text=True, timeout=300, env=checkout_env())


@pytest.mark.parametrize("check", [("check", "."), ("format", "--check", ".")], ids=["lint", "format"])
def test_the_checkout_passes_ruff(check):
    done = _ruff(*check)
    assert done.returncode == 0, f"ruff {' '.join(check)} (fix with `ruff check --fix .` / `ruff format .`):\n{done.stdout}{done.stderr}"


def test_ruff_with_the_checkouts_rules_refuses_unsorted_imports_and_unformatted_code(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("import sys\nimport os\nx=zip([1],[2])\n")
    config = str(REPO_ROOT / "pyproject.toml")
    lint = _ruff("check", "--no-cache", "--config", config, "--output-format", "concise", str(bad), cwd=tmp_path)
    assert lint.returncode == 1 and {"I001", "B905"} <= {word for word in lint.stdout.split() if word[:1].isupper()}, lint.stdout
    assert _ruff("format", "--check", "--no-cache", "--config", config, str(bad), cwd=tmp_path).returncode == 1


def test_ci_lints_formats_and_type_checks_before_the_tests():
    lines = [line.strip() for line in (REPO_ROOT / ".ci" / "run").read_text().splitlines()]
    where = {step: next((i for i, line in enumerate(lines) if line.startswith(step)), None) for step in (
        "./install.sh", "python3 -m ruff check .", "python3 -m ruff format --check .", "python3 -m mypy", "python3 -m pytest")}  # fmt: skip
    missing = [step for step, index in where.items() if index is None]
    assert not missing, f".ci/run lacks {missing}"
    assert (
        where["./install.sh"] < min(where["python3 -m ruff check ."], where["python3 -m mypy"])
        and max(where.values()) == where["python3 -m pytest"]
    )
