"""Every fast verification check passes through the registry; slow ones under ``-m slow``.

Fast total (2 cores): about 10 s in process. The slow families (reaming-energy-balance and
reaming-convergence: the default case over 20 and 5 × 30 frames) take tens of minutes:
``pytest -m slow tests/verification``.
"""

from __future__ import annotations

import json

import pytest

from thrsim.verification import registry, run_checks, select

FAST = [c.name for c in registry().values() if not c.slow]
SLOW = [c.name for c in registry().values() if c.slow]


def _report(records) -> str:
    return "\n".join(
        f"{r.name}: value={r.value} reference={r.reference} error={r.error} tolerance={r.tolerance} passed={r.passed} details={json.dumps(r.details, default=str)}"
        for r in records
    )


@pytest.mark.timeout(120)
@pytest.mark.parametrize("family", FAST)
def test_fast_check_passes(family: str) -> None:
    records = run_checks([family])
    assert records, f"{family} produced no records"
    check = registry()[family]
    assert {r.name for r in records} == set(check.figures), "figures declared in the registry must match those produced"
    for r in records:
        assert r.check == family and r.slow is False and r.seconds > 0
    assert all(r.passed for r in records), _report(records)


@pytest.mark.slow
@pytest.mark.timeout(1800)
@pytest.mark.parametrize("family", SLOW)
def test_slow_check_passes(family: str) -> None:
    records = run_checks([family])
    assert records and all(r.passed for r in records), _report(records)


def test_registry_names_are_unique_and_selection_works() -> None:
    checks = registry()
    figures = [f for c in checks.values() for f in c.figures]
    assert len(figures) == len(set(figures))
    assert not set(figures) & set(checks)
    assert [c.name for c, _ in select()] == FAST
    assert [c.name for c, _ in select(include_slow=True)] == list(checks)
    assert select(["jc-uniaxial-rate-1"]) == [(checks["jc-uniaxial"], {"jc-uniaxial-rate-1"})]
    with pytest.raises(KeyError):
        select(["no-such-check"])


def test_figure_selection_keeps_only_that_figure() -> None:
    records = run_checks(["jc-uniaxial-rate-1000"])
    assert [r.name for r in records] == ["jc-uniaxial-rate-1000"]
    assert records[0].passed


def test_a_crashing_check_is_a_failed_record(monkeypatch) -> None:
    import thrsim.verification as verification
    from thrsim.verification.base import Check

    def boom():
        raise RuntimeError("kaboom")

    monkeypatch.setattr(verification, "registry", lambda: {"boom": Check("boom", "always crashes", boom, ("boom",))})
    [record] = verification.run_checks()
    assert record.passed is False and "kaboom" in record.details["exception"]
