"""Linear-tet kinematics, lumped mass and per-element mass scaling (pure NumPy, no I/O).

Kinematics are geometrically linear (small strain, reference-configuration gradients): cortical
bone is brittle, its elastic strain is below 0.3 % and elements are deleted by damage before they
distort or rotate much while the bone is held; in exchange every step reuses the precomputed
gradients. Contact is always evaluated in the current (deformed) positions.

Mass scaling: the unscaled Courant limit of the 0.45 mm mesh is ~1e-8 s (~1.8 million steps
per 1/60 s frame). Each element whose own limit L_e/c_d is below the target step gets its density
raised just enough to reach it: ρ'_e = max(ρ, (λ+2μ)·(Δt_target / (s·h_e))²), with h_e its
smallest altitude and s the safety factor. Physical time is untouched, so the Johnson–Cook rate
term stays right; the price is extra inertia, reported as kinetic ÷ internal energy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thrsim.geometry.tet_metrics import minimum_altitudes, signed_volumes


def shape_gradients(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """∂N_a/∂x of the four linear shape functions of every tet, (E, 4, 3).

    With the edge vectors e1, e2, e3 from node 0, ∇N_1 = (e2 × e3)/det, ∇N_2 = (e3 × e1)/det,
    ∇N_3 = (e1 × e2)/det, det = e1·(e2 × e3): a closed form in elementwise arithmetic, so the
    gradients are bit-identical on every x86-64 machine (a LAPACK inverse differs by an ulp
    between BLAS CPU kernels, enough to change a reaming trajectory).
    """
    x = nodes[tets]  # (E, 4, 3)
    e1, e2, e3 = x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]
    c23, c31, c12 = _cross(e2, e3), _cross(e3, e1), _cross(e1, e2)
    det = e1[:, 0] * c23[:, 0] + e1[:, 1] * c23[:, 1] + e1[:, 2] * c23[:, 2]
    grads = np.empty((len(tets), 4, 3))
    grads[:, 1] = c23 / det[:, None]
    grads[:, 2] = c31 / det[:, None]
    grads[:, 3] = c12 / det[:, None]
    grads[:, 0] = -(grads[:, 1] + grads[:, 2] + grads[:, 3])
    return grads


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a × b written out (elementwise products only)."""
    return np.stack(
        [a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2], a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]],
        axis=1,
    )


@dataclass(frozen=True)
class MassScaling:
    """Per-element densities after scaling and the figures to report."""

    element_density: np.ndarray  # (E,) kg/m³ actually used
    stable_dt_s: float  # Courant limit of the scaled mesh, times the safety factor
    unscaled_dt_s: float  # same for the physical density
    scaled_fraction: float  # fraction of elements whose density was raised
    mass_increase: float  # scaled mass ÷ physical mass

    def as_dict(self) -> dict:
        return {
            "stable_dt_s": self.stable_dt_s,
            "unscaled_dt_s": self.unscaled_dt_s,
            "scaled_element_fraction": self.scaled_fraction,
            "mass_increase_factor": self.mass_increase,
        }


def mass_scaling(
    nodes: np.ndarray,
    tets: np.ndarray,
    density: float | np.ndarray,
    p_wave_modulus: float | np.ndarray,
    target_dt_s: float | None,
    safety: float,
) -> MassScaling:
    """Densities that let the whole mesh run at ``target_dt_s`` (None: no scaling); density and the
    P-wave modulus λ + 2μ per element or one for all."""
    altitude = minimum_altitudes(nodes, tets)
    wave_speed = np.sqrt(p_wave_modulus / density)
    unscaled = safety * float((altitude / wave_speed).min())
    rho = np.broadcast_to(np.asarray(density, dtype=np.float64), (len(tets),)).copy()
    if target_dt_s is not None:
        required = p_wave_modulus * (target_dt_s / (safety * altitude)) ** 2
        rho = np.maximum(rho, required)
    volume = np.abs(signed_volumes(nodes, tets))
    stable = safety * float((altitude / np.sqrt(p_wave_modulus / rho)).min())
    return MassScaling(
        element_density=rho,
        stable_dt_s=stable,
        unscaled_dt_s=unscaled,
        scaled_fraction=float(np.mean(rho > density)),
        mass_increase=float((rho * volume).sum() / (np.asarray(density) * volume).sum()),
    )


def lumped_nodal_mass(n_nodes: int, tets: np.ndarray, element_mass: np.ndarray) -> np.ndarray:
    """Row-sum lumping: a quarter of each tet's mass to each of its nodes."""
    mass = np.zeros(n_nodes)
    np.add.at(mass, tets.ravel(), np.repeat(element_mass / 4.0, 4))
    return mass


def node_element_csr(n_nodes: int, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Node → (element·4 + local index) in CSR form: lets a parallel loop over nodes gather
    element forces without write races (no atomics in Numba)."""
    flat = tets.ravel().astype(np.int64)
    order = np.argsort(flat, kind="stable")
    counts = np.bincount(flat, minlength=n_nodes)
    offsets = np.zeros(n_nodes + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets, order.astype(np.int64)
