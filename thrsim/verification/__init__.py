"""Verification suite of the explicit solver (issue 3, item 5): checks against closed forms,
conservation laws, convergence and an independent solver (CalculiX).

Each module holds one family of checks and exposes ``CHECKS``, a list of :class:`Check`;
this registry collects them in order. A check is a pure computation returning
:class:`CheckResult` records (no printing); ``thrsim verify`` runs them and reports.

To add a family: write ``thrsim/verification/<family>.py`` with ``CHECKS = [Check(...)]`` and
list the module in ``_MODULES`` below. Slow checks (``Check(slow=True)``) run only with
``thrsim verify --slow`` (or when named with ``--only``) and in ``pytest -m slow``.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Iterable

from thrsim.verification.base import Check, CheckResult

_MODULES = (
    "thrsim.verification.material_checks",  # jc-uniaxial, damage-single-element, crushable-foam
    "thrsim.verification.patch_test",  # patch-test
    "thrsim.verification.wave",  # column-wave
    "thrsim.verification.bookkeeping",  # deletion-bookkeeping
    "thrsim.verification.energy",  # energy-conservation, dt-convergence
    "thrsim.verification.calculix",  # calculix
    "thrsim.verification.reaming_checks",  # reaming-dt-convergence (slow)
)


def registry() -> dict[str, Check]:
    """Every registered check family by name, in suite order."""
    checks: dict[str, Check] = {}
    for module_name in _MODULES:
        module = importlib.import_module(module_name)
        for check in getattr(module, "CHECKS", []):
            if check.name in checks:
                raise ValueError(f"duplicate verification check name {check.name!r}")
            checks[check.name] = check
    return checks


def select(names: Iterable[str] | None = None, include_slow: bool = False) -> list[tuple[Check, set[str] | None]]:
    """Families to run: all non-slow ones (plus slow ones with ``include_slow``), or those named.

    A name may be a family (``patch-test``) or one of its figures (``jc-uniaxial-rate-1``); a
    figure name runs its family and keeps only that figure. Named checks run even when slow.
    Unknown names raise ``KeyError`` listing what exists.
    """
    checks = registry()
    if not names:
        return [(c, None) for c in checks.values() if include_slow or not c.slow]
    chosen: dict[str, set[str] | None] = {}
    for name in names:
        if name in checks:
            chosen[name] = None
            continue
        family = next((c.name for c in checks.values() if name in c.figures), None)
        if family is None:
            known = ", ".join(f"{c.name} ({', '.join(c.figures)})" for c in checks.values())
            raise KeyError(f"unknown verification check {name!r}; known: {known}")
        if chosen.get(family, set()) is not None:
            chosen.setdefault(family, set()).add(name)  # type: ignore[union-attr]
    return [(checks[n], figures) for n, figures in chosen.items()]


def run_checks(
    names: Iterable[str] | None = None, include_slow: bool = False, progress: Callable[[Check], None] | None = None
) -> list[CheckResult]:
    """Run the selected checks; a check that raises becomes one failed record carrying the error."""
    results: list[CheckResult] = []
    for check, figures in select(names, include_slow):
        if progress:
            progress(check)
        started = time.perf_counter()
        try:
            records = check.run()
        except Exception as error:  # a crash is a failed check, reported, not a traceback
            records = [CheckResult(name=check.name, figure=check.description, reference=None, value=None, error=None,
                                   tolerance=None, passed=False, details={"exception": f"{type(error).__name__}: {error}"})]  # fmt: skip
        elapsed = time.perf_counter() - started
        for record in records:
            record.check = check.name
            record.slow = check.slow
            if not record.seconds:
                record.seconds = elapsed
        if figures:
            records = [r for r in records if r.name in figures] or records
        results.extend(records)
    return results


__all__ = ["Check", "CheckResult", "registry", "run_checks", "select"]
