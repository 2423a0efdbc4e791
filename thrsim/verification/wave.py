"""Constrained-column (1-D strain) elastic wave: front speed c_d and stress jump ρ·c_d·v0.

A long column of tets along x has its lateral displacements constrained (uniaxial strain); its
end x = 0 is driven at constant velocity v0 into the column. The compressive front must travel
at c_d = √((λ+2μ)/ρ) and carry the stress σ_xx = −ρ·c_d·v0 behind it. Elastic (A huge), no mass
scaling (the unscaled Courant step), no bulk viscosity; the bulk viscosity's effect on the
plateau is reported in the details.
"""

from __future__ import annotations

import math

import numpy as np

from thrsim.config import BoneMaterial
from thrsim.geometry.box_mesh import box_mesh
from thrsim.physics.explicit import LINEAR_BULK_VISCOSITY, ExplicitSolid
from thrsim.verification.base import Check, CheckResult, Stopwatch, elastic_hardening, no_damage, numba_threads, prescribe_velocity, result

LENGTH_M = 0.1
CELL_M = 0.5e-3
V0_M_S = 0.1
SPEED_TOLERANCE = 1e-2
JUMP_TOLERANCE = 5e-3


def constrained_column(
    material: BoneMaterial,
    hardening,
    damage,
    v0: float,
    end_time: float | None,
    bulk_viscosity: float,
    target_dt_s: float | None = None,
    length: float = LENGTH_M,
    cell: float = CELL_M,
    record: bool = True,
):
    """Run the column; returns the solid, the element centroids' x and σ_xx history (steps, E)."""
    n = int(round(length / cell))
    mesh = box_mesh((n, 1, 1), (length, cell, cell))
    solid = ExplicitSolid(
        mesh, material, hardening, damage, target_dt_s=target_dt_s, held_nodes=np.zeros(0, dtype=np.int64), bulk_viscosity=bulk_viscosity
    )
    driven = mesh.node_sets["xmin"]
    c_d = material.dilatational_wave_speed_m_s
    end_time = end_time if end_time is not None else 0.8 * length / c_d
    steps = int(math.ceil(end_time / solid.dt))
    history, times = [], []
    solid.velocity[driven, 0] = v0
    for _ in range(steps):
        solid.step()
        solid.velocity[:, 1:] = 0.0  # lateral constraint: uniaxial strain
        solid.du[:, 1:] = 0.0
        solid.displacement[:, 1:] = 0.0
        prescribe_velocity(solid, driven, 0, v0)
        if record:
            history.append(solid.stress[:, 0].copy())
            # the stress just computed belongs to the start of the step
            times.append(solid.time - solid.dt)
    x = mesh.centroids[:, 0]
    return solid, x, np.array(times), np.array(history) if record else None


def _slab_mean(history: np.ndarray, x: np.ndarray, centre: float, half: float) -> np.ndarray:
    pick = np.abs(x - centre) <= half
    return history[:, pick].mean(axis=1)


def _crossing_time(times: np.ndarray, signal: np.ndarray, level: float) -> float:
    """First time the signal passes ``level`` (its sign taken from the level), linearly interpolated."""
    s = signal * np.sign(level)
    lv = abs(level)
    k = int(np.argmax(s >= lv))
    if s[k] < lv or k == 0:
        return float("nan")
    return float(times[k - 1] + (lv - s[k - 1]) / (s[k] - s[k - 1]) * (times[k] - times[k - 1]))


def column_wave() -> list[CheckResult]:
    material = BoneMaterial()
    rho, c_d = material.density_kg_m3, material.dilatational_wave_speed_m_s
    jump_ref = -rho * c_d * V0_M_S
    with Stopwatch() as watch, numba_threads(1):
        solid, x, times, history = constrained_column(material, elastic_hardening(), no_damage(), V0_M_S, None, bulk_viscosity=0.0)
        x1, x2 = 0.25 * LENGTH_M, 0.65 * LENGTH_M
        t1 = _crossing_time(times, _slab_mean(history, x, x1, CELL_M), 0.5 * jump_ref)
        t2 = _crossing_time(times, _slab_mean(history, x, x2, CELL_M), 0.5 * jump_ref)
        speed = (x2 - x1) / (t2 - t1)
        # plateau behind the front at the end (front near 0.8 L): mean σ_xx over 0.1 L … 0.5 L
        behind = (x > 0.1 * LENGTH_M) & (x < 0.5 * LENGTH_M)
        jump = float(history[-1, behind].mean())
        ripple = float((history[-1, behind].max() - history[-1, behind].min()) / abs(jump_ref))
        viscous, xv, _, hv = constrained_column(
            material, elastic_hardening(), no_damage(), V0_M_S, None, bulk_viscosity=LINEAR_BULK_VISCOSITY
        )
        jump_viscous = float(hv[-1, behind].mean())
        ripple_viscous = float((hv[-1, behind].max() - hv[-1, behind].min()) / abs(jump_ref))
    details = {
        "dt_s": solid.dt,
        "steps": int(len(times)),
        "elements": solid.mesh.n_tets,
        "cell_m": CELL_M,
        "v0_m_s": V0_M_S,
        "stations_m": [x1, x2],
        "plateau_ripple_fraction": ripple,
        "with_bulk_viscosity_0.06": {
            "stress_jump_mpa": -jump_viscous / 1e6,
            "relative_error": abs(jump_viscous - jump_ref) / abs(jump_ref),
            "plateau_ripple_fraction": ripple_viscous,
        },
    }
    return [
        result("column-wave-speed", "front speed between two stations (50 % crossing) vs c_d = √((λ+2μ)/ρ)",
               value=speed, reference=c_d, tolerance=SPEED_TOLERANCE, units="m/s", details=details, seconds=watch.seconds),
        result("column-wave-stress-jump", "mean −σ_xx behind the front vs ρ·c_d·v0 (no bulk viscosity)",
               value=-jump / 1e6, reference=-jump_ref / 1e6, tolerance=JUMP_TOLERANCE, units="MPa", seconds=watch.seconds),
    ]  # fmt: skip


CHECKS = [
    Check(
        "column-wave",
        "constrained-column elastic wave: speed and stress jump",
        column_wave,
        ("column-wave-speed", "column-wave-stress-jump"),
    )
]
