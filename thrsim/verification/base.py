"""Result records, the check descriptor and small helpers shared by the verification checks.

Every check is a pure computation: it builds its problem, runs thrsim's kernels or solver (and,
for the cross-check, CalculiX), and returns :class:`CheckResult` records. Nothing here prints.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field

import numba


@dataclass
class CheckResult:
    """One verified figure: a measured ``value`` against a ``reference`` within a ``tolerance``.

    ``error`` is the figure's error measure (its definition is in ``figure``; relative unless
    stated), ``passed`` is ``error <= tolerance`` unless the check says otherwise. ``seconds``
    is the wall time of the computation behind the figure (shared figures share it).
    """

    name: str
    figure: str
    reference: float | None
    value: float | None
    error: float | None
    tolerance: float | None
    passed: bool
    seconds: float = 0.0
    slow: bool = False
    check: str = ""
    units: str = ""
    details: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Check:
    """A family of figures computed together; ``run()`` returns its records, named ``figures``."""

    name: str
    description: str
    run: Callable[[], list[CheckResult]]
    figures: tuple[str, ...] = ()
    slow: bool = False


def relative_error(value: float, reference: float) -> float:
    """|value − reference| / |reference| (absolute error when the reference is 0)."""
    scale = abs(reference)
    return abs(value - reference) / scale if scale > 0 else abs(value - reference)


def result(
    name: str,
    figure: str,
    value: float,
    reference: float | None,
    tolerance: float,
    *,
    error: float | None = None,
    units: str = "",
    details: dict | None = None,
    seconds: float = 0.0,
) -> CheckResult:
    """A record whose error defaults to the relative error of value against reference."""
    if error is None:
        error = relative_error(value, reference) if reference is not None else abs(value)
    passed = bool(error is not None and math.isfinite(error) and error <= tolerance)
    return CheckResult(
        name=name, figure=figure, reference=None if reference is None else float(reference), value=float(value),
        error=float(error), tolerance=float(tolerance), passed=passed, units=units, details=details or {}, seconds=seconds,
    )  # fmt: skip


@contextlib.contextmanager
def numba_threads(n: int = 1) -> Iterator[None]:
    """Run the Numba kernels on ``n`` threads: the verification meshes are tiny, and on a loaded
    machine a parallel region over a few hundred elements costs more in thread wake-ups (≈10×
    measured) than it saves."""
    previous = numba.get_num_threads()
    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(previous)


class Stopwatch:
    """``with Stopwatch() as w: ...; w.seconds``"""

    def __enter__(self) -> Stopwatch:
        self._start = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc) -> None:
        self.seconds = time.perf_counter() - self._start


def elastic_hardening():
    """JC hardening with a yield stress no test reaches: a purely elastic solid."""
    from thrsim.config import JohnsonCookHardening

    return JohnsonCookHardening(a_pa=1e15, b_pa=0.0)


def no_damage():
    """JC damage that never initiates (fracture strain 1e9)."""
    from thrsim.config import JohnsonCookDamage

    return JohnsonCookDamage(d1=1e9, d2=0.0, displacement_at_failure_m=1.0)


def prescribe_velocity(solid, nodes, component: int, value: float) -> None:
    """After a step, impose velocity ``value`` on ``component`` of ``nodes`` as if it had been a
    kinematic constraint during the step (v, Δu and u corrected consistently)."""
    dt = solid.dt
    solid.displacement[nodes, component] += dt * value - solid.du[nodes, component]
    solid.du[nodes, component] = dt * value
    solid.velocity[nodes, component] = value
