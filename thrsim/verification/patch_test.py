"""Patch test: a linear displacement field on a distorted tet mesh is reproduced exactly.

Every node of an irregular (jittered) box mesh is given u = H·X with a general (non-symmetric)
displacement gradient H; the boundary nodes are held. One solver step must then produce zero
force at every interior node (to round-off, relative to the boundary reactions) and the same
stress C:sym(H) in every element, whatever their shape.
"""

from __future__ import annotations

import numpy as np

from thrsim.config import BoneMaterial
from thrsim.geometry.box_mesh import box_mesh
from thrsim.physics.explicit import ExplicitSolid
from thrsim.verification.base import Check, CheckResult, Stopwatch, elastic_hardening, no_damage, numba_threads, result

GRADIENT = np.array([[1.0e-3, 0.4e-3, -0.2e-3], [-0.1e-3, -0.5e-3, 0.3e-3], [0.25e-3, 0.15e-3, 0.7e-3]])
RESIDUAL_TOLERANCE = 1e-12
STRESS_TOLERANCE = 1e-12


def patch_test() -> list[CheckResult]:
    material = BoneMaterial()
    with Stopwatch() as watch, numba_threads(1):
        mesh = box_mesh((4, 4, 4), (2e-3, 2.5e-3, 3e-3), scheme="five", jitter=0.3, seed=7)
        boundary, interior = mesh.node_sets["boundary"], mesh.node_sets["interior"]
        solid = ExplicitSolid(mesh, material, elastic_hardening(), no_damage(), target_dt_s=None, held_nodes=boundary, bulk_viscosity=0.0)
        u = mesh.nodes @ GRADIENT.T
        solid.du[:] = u
        solid.displacement[:] = u
        solid.step()
        # interior nodes started at rest: their velocity now is dt·f/m
        interior_force = solid.velocity[interior] * solid.nodal_mass[interior, None] / solid.dt
        nodal = np.zeros((mesh.n_nodes, 3))
        np.add.at(nodal, solid.tets.ravel(), solid.element_force.reshape(-1, 3))
        boundary_force = np.abs(nodal[boundary]).max()
        residual = float(np.abs(interior_force).max() / boundary_force)
        assembled = float(np.abs(nodal[interior]).max() / boundary_force)
        eps = 0.5 * (GRADIENT + GRADIENT.T)
        lam, mu = material.lame_lambda_pa, material.shear_modulus_pa
        sigma = lam * np.trace(eps) * np.eye(3) + 2 * mu * eps
        exact = np.array([sigma[0, 0], sigma[1, 1], sigma[2, 2], sigma[0, 1], sigma[1, 2], sigma[2, 0]])
        stress_error = float(np.abs(solid.stress - exact).max() / np.abs(exact).max())
        quality = mesh.quality()
    details = {
        "elements": mesh.n_tets,
        "interior_nodes": int(len(interior)),
        "min_quality": quality.min_quality,
        "assembled_interior_residual_ratio": assembled,
    }
    return [
        result("patch-test-residual", "max interior nodal force ÷ max boundary reaction for u = H·X on a jittered mesh",
               value=residual, reference=0.0, error=residual, tolerance=RESIDUAL_TOLERANCE, details=details, seconds=watch.seconds),
        result("patch-test-stress", "max |σ_e − C:sym(H)| ÷ max |C:sym(H)| over all elements",
               value=stress_error, reference=0.0, error=stress_error, tolerance=STRESS_TOLERANCE, seconds=watch.seconds),
    ]  # fmt: skip


CHECKS = [
    Check("patch-test", "constant-strain patch test on a distorted tet mesh", patch_test, ("patch-test-residual", "patch-test-stress"))
]
