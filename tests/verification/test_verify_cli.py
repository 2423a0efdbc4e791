"""``thrsim verify``: JSON contract, exit codes, --only."""

from __future__ import annotations

import json

import pytest
from checkout_cli import run_thrsim
from typer.testing import CliRunner

from thrsim.cli import app

KEYS = {"name", "figure", "reference", "value", "error", "tolerance", "passed", "seconds", "slow"}


@pytest.mark.timeout(300)
def test_verify_json_subprocess_runs_every_fast_check() -> None:
    completed = run_thrsim("verify", "--json", timeout=280)
    assert completed.returncode == 0, completed.stdout[-3000:] + completed.stderr[-3000:]
    payload = json.loads(completed.stdout)  # exactly one JSON object on stdout
    assert payload["passed"] is True
    assert payload["skipped_slow"] == ["reaming-dt-convergence"]
    checks = payload["checks"]
    assert len(checks) >= 20
    for check in checks:
        assert KEYS <= set(check), check
        assert check["passed"] is True and check["slow"] is False
    names = {c["check"] for c in checks}
    assert {"jc-uniaxial", "patch-test", "column-wave", "damage-single-element", "deletion-bookkeeping",
            "energy-conservation", "dt-convergence", "calculix"} <= names  # fmt: skip


def test_verify_only_and_table() -> None:
    result = CliRunner().invoke(app, ["verify", "--only", "patch-test,jc-uniaxial-rate-1"])
    assert result.exit_code == 0, result.output
    assert "patch-test-residual" in result.output and "jc-uniaxial-rate-1" in result.output
    assert "3/3 passed" in result.output


def test_verify_list_json() -> None:
    result = CliRunner().invoke(app, ["verify", "--list", "--json"])
    assert result.exit_code == 0
    listed = {c["name"]: c for c in json.loads(result.output)["checks"]}
    assert listed["reaming-dt-convergence"]["slow"] is True
    assert "calculix-wall-stress" in listed["calculix"]["figures"]


def test_verify_exit_code_1_when_a_check_fails(monkeypatch) -> None:
    import thrsim.verification as verification
    from thrsim.verification.base import Check, CheckResult

    def failing():
        return [CheckResult(name="always-fails", figure="a figure that never passes", reference=1.0, value=2.0, error=1.0, tolerance=0.1, passed=False)]

    monkeypatch.setattr(verification, "registry", lambda: {"always-fails": Check("always-fails", "fails", failing, ("always-fails",))})
    result = CliRunner().invoke(app, ["verify", "--json"])
    assert result.exit_code == 1
    payload = json.loads(result.output)
    assert payload["passed"] is False and payload["checks"][0]["name"] == "always-fails"


def test_verify_unknown_name_is_a_usage_error() -> None:
    completed = run_thrsim("verify", "--only", "no-such-check")
    assert completed.returncode == 2
    assert "unknown verification check" in completed.stderr
