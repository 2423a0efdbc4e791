"""Short reaming case, time-step convergence (slow): the default case at Δt and Δt/2.

The default bone patch (0.45 mm elements, 20,019 tets) is reamed at γ = 15°, θ = 30° for ten
frames with the default solver step (mass-scaled to ``SolverConfig.target_dt_s``) and with half
of it; the removed volume and the mean PEEQ of the remaining elements must agree within the
stated tolerances. Removal is a threshold process (element deletion) driven by a chattering
contact, so it converges in the mean over frames, not frame by frame; the reamer's advance
chatters by ±0.2 mm and is reported, not checked.

The study that set the default step, on the default 0.45 mm mesh (20,019 tets, ten frames,
u_f 0.45 mm): Δt 8e-6 / 4e-6 / 2e-6 s removed 38.6 / 35.2 / 34.3 mm³ with mean PEEQ
0.0170 / 0.0212 / 0.0225, i.e. halving 8e-6 → 4e-6 changed them by 9.6 % / 20 %, halving
4e-6 → 2e-6 by 2.8 % / 5.8 % (README, "Ground-truth solver"). The coarse 0.9 mm mesh
converges less well in mean PEEQ (4.8 % volume, 19 % mean PEEQ for 4e-6 → 2e-6), which is why
the check runs on the default mesh. About 3 minutes on 2 cores.
"""

from __future__ import annotations

from thrsim.config import BonePatchConfig, ReamingCaseConfig, SolverConfig
from thrsim.verification.base import Check, CheckResult, Stopwatch, result

FRAMES = 10
ELEMENT_SIZE_MM = 0.45
INCLINATION_DEG = 15.0
VOLUME_TOLERANCE = 0.05
PEEQ_TOLERANCE = 0.10


def reaming_dt_convergence() -> list[CheckResult]:
    try:
        from thrsim.physics.reaming import run_case
    except ImportError as error:
        return [CheckResult(name="reaming-dt-convergence-removed-volume", figure="thrsim.physics.reaming.run_case available",
                            reference=None, value=None, error=None, tolerance=None, passed=False,
                            details={"exception": f"{type(error).__name__}: {error}"})]  # fmt: skip
    from thrsim.geometry.bone_patch import generate_bone_patch

    base = ReamingCaseConfig(inclination_deg=INCLINATION_DEG, anteversion_deg=30.0, frames=FRAMES, bone=BonePatchConfig(element_size_mm=ELEMENT_SIZE_MM))
    mesh = generate_bone_patch(base.bone)
    summaries = []
    with Stopwatch() as watch:
        for factor in (1.0, 0.5):
            solver = SolverConfig(target_dt_s=base.solver.target_dt_s * factor)
            case = base.model_copy(update={"solver": solver})
            summaries.append(run_case(case, None, mesh=mesh))
    coarse, fine = summaries
    details = {
        "elements": mesh.n_tets,
        "frames": FRAMES,
        "dt_s": [s.get("dt_s") for s in summaries],
        "removed": [s.get("removed") for s in summaries],
        "removed_volume_mm3": [s.get("removed_volume_mm3") for s in summaries],
        "reamer_advance_mm": [s.get("reamer_advance_mm") for s in summaries],
        "max_kinetic_to_internal": [s.get("max_kinetic_to_internal") for s in summaries],
        "seconds_per_frame": [s.get("seconds_per_frame") for s in summaries],
        "end_reason": [s.get("end_reason") for s in summaries],
    }
    volume = result("reaming-dt-convergence-removed-volume", f"removed volume after {FRAMES} frames at Δt vs Δt/2 (Δt/2 = reference)",
                    value=coarse["removed_volume_mm3"], reference=fine["removed_volume_mm3"], tolerance=VOLUME_TOLERANCE,
                    units="mm³", details=details, seconds=watch.seconds)  # fmt: skip
    peeq = result("reaming-dt-convergence-mean-peeq", f"mean PEEQ of remaining elements after {FRAMES} frames at Δt vs Δt/2 (Δt/2 = reference)",
                  value=coarse["mean_peeq_active"], reference=fine["mean_peeq_active"], tolerance=PEEQ_TOLERANCE,
                  seconds=watch.seconds)  # fmt: skip
    # a case that removed nothing verifies nothing
    volume.passed = volume.passed and fine["removed"] > 0
    return [volume, peeq]


CHECKS = [
    Check("reaming-dt-convergence", "short reaming case (default mesh, γ 15°): removed volume and mean PEEQ at Δt vs Δt/2",
          reaming_dt_convergence, ("reaming-dt-convergence-removed-volume", "reaming-dt-convergence-mean-peeq"), slow=True),
]  # fmt: skip
