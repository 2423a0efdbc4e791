"""Cross-check against CalculiX (ccx): the elastic-plastic bar impact of :mod:`bar_impact`.

ccx runs first (its explicit increment is its own Courant estimate); thrsim then runs the same
problem at that increment (rounded so both end at the same time) with C = 0 and no bulk
viscosity. Figures: the deformation field d = u + v0·t·eₓ over all nodes (relative L2), the
displacement history of the node on the axis at mid-length, and the mean σ_xx and PEEQ of the
elements in the wall third of the bar (where the plastic front has passed). Differences of the
order of the strains (≲ 1 %) are expected: ccx's explicit step is geometrically nonlinear,
thrsim's small-strain; ccx interpolates a tabulated curve, thrsim evaluates the power law.
"""

from __future__ import annotations

import math

import numpy as np

from thrsim.config import BoneMaterial, JohnsonCookHardening
from thrsim.verification.bar_impact import BarImpact, ccx_available, run_ccx_bar, run_thrsim_bar
from thrsim.verification.base import Check, CheckResult, Stopwatch, numba_threads, result

FIELD_TOLERANCE = 2e-3
STRESS_TOLERANCE = 5e-3
PEEQ_TOLERANCE = 1e-2
CCX_TIMEOUT_S = 180.0


def calculix_cross_check() -> list[CheckResult]:
    if ccx_available() is None:
        return [CheckResult(name="calculix-available", figure="ccx (CalculiX) on PATH", reference=None, value=None, error=None,
                            tolerance=None, passed=False, details={"hint": "install calculix-ccx (install.sh does)"})]  # fmt: skip
    material = BoneMaterial()
    hardening = JohnsonCookHardening(c=0.0)  # ccx's *PLASTIC has no rate term
    problem = BarImpact()
    with Stopwatch() as total:
        ccx = run_ccx_bar(problem, material, hardening, timeout_s=CCX_TIMEOUT_S)
        steps = int(math.ceil(problem.end_time_s / ccx["dt_s"] - 1e-9))
        with numba_threads(1):
            # warm the kernels outside the timing (Numba's on-disk cache still has a load cost)
            run_thrsim_bar(
                BarImpact(end_time_s=problem.end_time_s / 50), material, hardening, dt_s=problem.end_time_s / steps, record_history=False
            )
            thr = run_thrsim_bar(problem, material, hardening, dt_s=problem.end_time_s / steps)
    mesh = thr["mesh"]
    v0 = problem.velocity_m_s
    moving = ~thr["held"]
    d_thr = thr["displacement"][moving].copy()
    d_ccx = ccx["displacement"][moving].copy()
    d_thr[:, 0] += v0 * thr["time_s"]
    d_ccx[:, 0] += v0 * ccx["time_s"]
    field = float(np.linalg.norm(d_thr - d_ccx) / np.linalg.norm(d_ccx))

    # mid-length probe history: ccx's printed times against thrsim's steps (interpolated)
    names = list(thr["probes"])
    column = 1 + names.index("half")
    h_thr, h_ccx = thr["history"], ccx["history"]
    deformation_thr = np.interp(h_ccx[:, 0], h_thr[:, 0], h_thr[:, column]) + v0 * h_ccx[:, 0]
    deformation_ccx = h_ccx[:, column] + v0 * h_ccx[:, 0]
    history = float(np.abs(deformation_thr - deformation_ccx).max() / np.abs(deformation_ccx).max())

    x = mesh.centroids[:, 0]
    zone = x < problem.length_m / 3
    sxx_thr, sxx_ccx = float(thr["stress"][zone, 0].mean()), float(ccx["stress"][zone, 0].mean())
    peeq_thr, peeq_ccx = float(thr["peeq"][zone].mean()), float(ccx["peeq"][zone].mean())
    thrsim_seconds = thr["setup_seconds"] + thr["solve_seconds"]
    ratio = ccx["seconds"] / thrsim_seconds
    details = {
        "elements": mesh.n_tets,
        "end_time_s": problem.end_time_s,
        "ccx_dt_s": ccx["dt_s"],
        "thrsim_dt_s": thr["dt_s"],
        "steps": thr["steps"],
        "ccx_seconds": ccx["seconds"],
        "thrsim_seconds": thrsim_seconds,
        "thrsim_solve_seconds": thr["solve_seconds"],
        "wall_time_ratio_ccx_over_thrsim": ratio,
        "max_peeq": {"thrsim": float(thr["peeq"].max()), "ccx": float(ccx["peeq"].max())},
        "min_sxx_mpa": {"thrsim": float(thr["stress"][:, 0].min() / 1e6), "ccx": float(ccx["stress"][:, 0].min() / 1e6)},
    }
    seconds = total.seconds
    return [
        result("calculix-displacement-field", "relative L2 difference of d = u + v0·t·eₓ over all nodes at the end time, thrsim vs ccx",
               value=field, reference=0.0, error=field, tolerance=FIELD_TOLERANCE, details=details, seconds=seconds),
        result("calculix-probe-history", "max |Δd| ÷ max |d| of the mid-length axis node over ccx's printed times",
               value=history, reference=0.0, error=history, tolerance=FIELD_TOLERANCE, seconds=seconds,
               details={"printed_times": ccx["printed_times"]}),
        result("calculix-wall-stress", "mean σ_xx of the elements in the wall third at the end time (ccx = reference)",
               value=sxx_thr / 1e6, reference=sxx_ccx / 1e6, tolerance=STRESS_TOLERANCE, units="MPa", seconds=seconds),
        result("calculix-wall-peeq", "mean PEEQ of the elements in the wall third at the end time (ccx = reference)",
               value=peeq_thr, reference=peeq_ccx, tolerance=PEEQ_TOLERANCE, seconds=seconds,
               details={"wall_time_ratio_ccx_over_thrsim": ratio}),
    ]  # fmt: skip


CHECKS = [
    Check(
        "calculix",
        "cross-check of an elastic-plastic bar impact against CalculiX (C3D4, explicit)",
        calculix_cross_check,
        ("calculix-displacement-field", "calculix-probe-history", "calculix-wall-stress", "calculix-wall-peeq"),
    )
]
