"""``thrsim verify``: JSON contract, exit codes, --only."""

from __future__ import annotations

import json

import pytest
from checkout_cli import run_thrsim
from typer.testing import CliRunner

from thrsim.cli import app

KEYS = {"name", "figure", "reference", "value", "error", "tolerance", "passed", "seconds", "slow"}


@pytest.mark.timeout(120)
def test_verify_json_through_the_real_command() -> None:
    """The command's JSON contract, end to end on two quick families. Every check itself runs
    once in the default suite, in test_verification_checks.py, not again here."""
    completed = run_thrsim("verify", "--json", "--only", "jc-uniaxial,patch-test", timeout=110)
    assert completed.returncode == 0, completed.stdout[-3000:] + completed.stderr[-3000:]
    payload = json.loads(completed.stdout)  # exactly one JSON object on stdout
    assert payload["passed"] is True and payload["families"] == ["jc-uniaxial", "patch-test"] and payload["skipped_slow"] == []
    checks = payload["checks"]
    assert {c["check"] for c in checks} == {"jc-uniaxial", "patch-test"} and len(checks) >= 4
    for check in checks:
        assert KEYS <= set(check), check
        assert check["passed"] is True and check["slow"] is False


def test_verify_default_runs_every_fast_family_and_names_the_slow_ones(monkeypatch) -> None:
    import thrsim.verification as verification
    from thrsim.verification.base import Check, CheckResult

    ran = []

    def family(name: str, slow: bool) -> Check:
        def run():
            ran.append(name)
            return [CheckResult(name=f"{name}-figure", figure=name, reference=1.0, value=1.0, error=0.0, tolerance=0.1, passed=True)]

        return Check(name, f"stand-in {name}", run, (f"{name}-figure",), slow=slow)

    checks = {c.name: c for c in (family("quick-a", False), family("quick-b", False), family("long", True))}
    monkeypatch.setattr(verification, "registry", lambda: checks)
    result = CliRunner().invoke(app, ["verify", "--json"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.output)
    assert payload["families"] == ["quick-a", "quick-b"] and payload["skipped_slow"] == ["long"] and ran == ["quick-a", "quick-b"]


def test_verify_only_and_table() -> None:
    result = CliRunner().invoke(app, ["verify", "--only", "patch-test,jc-uniaxial-rate-1"])
    assert result.exit_code == 0, result.output
    assert "patch-test-residual" in result.output and "jc-uniaxial-rate-1" in result.output
    assert "3/3 passed" in result.output


def test_verify_list_json() -> None:
    result = CliRunner().invoke(app, ["verify", "--list", "--json"])
    assert result.exit_code == 0
    listed = {c["name"]: c for c in json.loads(result.output)["checks"]}
    assert listed["reaming-convergence"]["slow"] is True and listed["reaming-energy-balance"]["slow"] is True
    assert "calculix-wall-stress" in listed["calculix"]["figures"]


def test_verify_exit_code_1_when_a_check_fails(monkeypatch) -> None:
    import thrsim.verification as verification
    from thrsim.verification.base import Check, CheckResult

    def failing():
        return [
            CheckResult(
                name="always-fails", figure="a figure that never passes", reference=1.0, value=2.0, error=1.0, tolerance=0.1, passed=False
            )
        ]

    monkeypatch.setattr(verification, "registry", lambda: {"always-fails": Check("always-fails", "fails", failing, ("always-fails",))})
    result = CliRunner().invoke(app, ["verify", "--json"])
    assert result.exit_code == 1
    payload = json.loads(result.output)
    assert payload["passed"] is False and payload["checks"][0]["name"] == "always-fails"


def test_verify_unknown_name_is_a_usage_error() -> None:
    completed = run_thrsim("verify", "--only", "no-such-check")
    assert completed.returncode == 2
    assert "unknown verification check" in completed.stderr
