"""Johnson–Cook plasticity and ductile damage, and the crushable foam of cancellous bone: pure kernels.

Hardening (thermal softening off) [Table 4]: ``σ_y = [A + B εᵖⁿ]·[1 + C ln(ε̇ᵖ/ε̇₀)]``, the rate
term only for ε̇ᵖ > ε̇₀, as in ABAQUS. Damage initiation [Table 8]: ω = Σ Δεᵖ / ε_f(η, ε̇ᵖ) with
``ε_f = [d1 + d2 exp(d3 η)][1 + d4 ln(ε̇ᵖ/ε̇₀)]``; the thesis constants give ε_f < 0 for every
triaxiality η, read explicitly as "initiate at first yield" and never used as a divisor.
Evolution is linear in the plastic displacement after initiation, D = L_e·Δεᵖ / u_f, and the
element is deleted at D ≥ 1. Cancellous bone yields on Deshpande and Fleck's crushable-foam
ellipse instead (:func:`foam_return`). The return mappings are written here because no library
offers them usable inside an explicit loop; the NumPy functions are the verification's closed forms.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from thrsim import portable_math as pm

#: smallest plastic increment considered, as ln Δ
_LOG_FLOOR = pm.log(1e-300)
_RETURN_ITERATIONS = 100
_RETURN_TOLERANCE = 1e-12


@njit(cache=True, inline="always")
def jc_yield_stress(peeq: float, peeq_rate: float, a: float, b: float, n: float, c: float, rate0: float) -> float:
    """Johnson–Cook flow stress (Pa) at equivalent plastic strain and its rate (1/s)."""
    hardening = a + b * pm.pow(peeq, n) if peeq > 0.0 else a
    if peeq_rate > rate0:
        hardening *= 1.0 + c * pm.log(peeq_rate / rate0)
    return hardening


@njit(cache=True)
def jc_radial_return(
    q_trial: float,
    peeq: float,
    static: float,
    dt: float,
    shear_modulus: float,
    a: float,
    b: float,
    n: float,
    c: float,
    rate0: float,
) -> float:
    """Plastic strain increment Δεᵖ ≥ 0 that returns a trial von Mises stress to the JC surface;
    ``static`` is the flow stress at ``peeq`` and rate 0 (:func:`jc_yield_stress`; the caller keeps
    it per element, since most elements with plastic history stay elastic step after step).

    Solves g(Δ) = q_trial − 3GΔ − σ_y(εᵖ + Δ, Δ/dt) = 0, strictly decreasing in Δ. The root can
    lie many decades below q_trial/3G (εᵖⁿ with n = 0.08 and the rate logarithm both have
    infinite slope at zero), so Newton's method runs on z = ln Δ, where both become smooth,
    safeguarded by bisection in z. Returns 0 when the trial state is elastic.
    """
    if q_trial <= static:
        return 0.0
    z_lo, z_hi = _LOG_FLOOR, pm.log(q_trial / (3.0 * shear_modulus))
    # start from the elastic-perfectly-plastic estimate, itself an upper bound of the root
    excess = q_trial - static
    z = min(pm.log(excess / (3.0 * shear_modulus)), z_hi)
    for _ in range(_RETURN_ITERATIONS):
        x = pm.exp(z)
        p = peeq + x
        rate = x / dt
        rate_factor = 1.0 + c * pm.log(rate / rate0) if rate > rate0 else 1.0
        static = a + b * pm.pow(p, n)
        g = q_trial - 3.0 * shear_modulus * x - static * rate_factor
        if abs(g) <= _RETURN_TOLERANCE * q_trial:
            return x
        if g > 0.0:
            z_lo = z
        else:
            z_hi = z
        # dg/dz = −Δ·(3G + ∂σ_y/∂Δ): hardening slope b·n·pⁿ⁻¹ and rate slope static·c/Δ
        slope = x * (3.0 * shear_modulus + b * n * pm.pow(p, n - 1.0) * rate_factor)
        if rate > rate0:
            slope += static * c
        newton = z + g / slope
        z = newton if z_lo < newton < z_hi else 0.5 * (z_lo + z_hi)
        if z_hi - z_lo <= _RETURN_TOLERANCE:
            break
    return pm.exp(z)


@njit(cache=True, inline="always")
def jc_fracture_strain(triaxiality: float, peeq_rate: float, d1: float, d2: float, d3: float, d4: float, rate0: float) -> float:
    """ε_f(η, ε̇ᵖ); may be ≤ 0 (then damage initiates at first yield, see module docstring)."""
    strain = d1 + d2 * pm.exp(d3 * triaxiality)
    if peeq_rate > rate0:
        strain *= 1.0 + d4 * pm.log(peeq_rate / rate0)
    return strain


@njit(cache=True, inline="always")
def damage_initiation_increment(
    dpeeq: float, triaxiality: float, peeq_rate: float, d1: float, d2: float, d3: float, d4: float, rate0: float
) -> float:
    """Increment of the initiation criterion ω; ≥ 1 means initiated (instantly when ε_f ≤ 0)."""
    if dpeeq <= 0.0:
        return 0.0
    strain = jc_fracture_strain(triaxiality, peeq_rate, d1, d2, d3, d4, rate0)
    if strain <= 0.0:
        return 1.0
    return dpeeq / strain


def flow_curve(peeq: np.ndarray, peeq_rate: float, a: float, b: float, n: float, c: float, rate0: float) -> np.ndarray:
    """Closed-form JC flow stress over an array of plastic strains (the verification reference)."""
    peeq = np.asarray(peeq, dtype=float)
    rate_factor = 1.0 + c * np.log(peeq_rate / rate0) if peeq_rate > rate0 else 1.0
    return (a + b * np.where(peeq > 0, peeq, 0.0) ** n) * rate_factor


def characteristic_length(volume: np.ndarray) -> np.ndarray:
    """L_e for damage evolution: edge of the regular tet with the element's volume, (6√2·V)^(1/3)."""
    return pm.cbrt_array(6.0 * math.sqrt(2.0) * np.abs(np.asarray(volume, dtype=np.float64)))


@njit(cache=True, inline="always")
def crushed_flow_stress(
    peeq: float,
    peeq_rate: float,
    a: float,
    b: float,
    n: float,
    c: float,
    rate0: float,
    eps_d: float,
    coef_d: float,
    exp_d: float,
    cap: float,
) -> float:
    """Compressive flow stress σ_c (Pa) of the crushable foam: the JC plateau times densification,
    at most ``cap`` (the tissue's strength, reached before the densification strain ε_D)."""
    if peeq >= eps_d:
        return cap
    densify = pm.pow(eps_d / (eps_d - peeq), exp_d) / coef_d
    return min(cap, jc_yield_stress(peeq, peeq_rate, a, b, n, c, rate0) * max(1.0, densify))


@njit(cache=True)
def foam_return(
    q_trial: float,
    mean_trial: float,
    peeq: float,
    static: float,
    dt: float,
    shear_modulus: float,
    bulk_modulus: float,
    alpha: float,
    a: float,
    b: float,
    n: float,
    c: float,
    rate0: float,
    eps_d: float,
    coef_d: float,
    exp_d: float,
    cap: float,
) -> tuple[float, float]:
    """Plastic multiplier Δγ and ε̂ increment returning a trial stress to the crushable-foam surface.

    Associated flow on f = √(q² + α²p²) gives q = q_tr/(1 + 6GΔγ), p = p_tr/(1 + 2Kα²Δγ) and
    Δε̂ = σ:Δεᵖ/σ_c = 2βΔγ·f with β = √(1 + α²/9); the residual f − β·σ_c(ε̂ + Δε̂) falls
    strictly with Δγ. Newton's method on z = ln Δγ (as :func:`jc_radial_return`, for the same
    infinite slopes at zero), safeguarded by bisection. Returns (0, 0) when the trial is elastic.
    ``static`` is σ_c at ``peeq`` and rate 0 (:func:`crushed_flow_stress`), kept per element by the caller.
    """
    beta = math.sqrt(1.0 + alpha * alpha / 9.0)
    f_trial = math.sqrt(q_trial * q_trial + alpha * alpha * mean_trial * mean_trial)
    if f_trial <= beta * static:
        return 0.0, 0.0
    shear_rate = 6.0 * shear_modulus
    bulk_rate = 2.0 * bulk_modulus * alpha * alpha
    excess = f_trial / (beta * static) - 1.0
    # f(Δγ) ≤ f_tr/(1 + min rate·Δγ) and σ_c ≥ its static value: the residual is negative at z_hi
    z_lo, z_hi = _LOG_FLOOR, pm.log(excess / min(shear_rate, bulk_rate))
    z = pm.log(excess / max(shear_rate, bulk_rate))
    gamma = dpeeq = 0.0
    for _ in range(_RETURN_ITERATIONS):
        gamma = pm.exp(z)
        q = q_trial / (1.0 + shear_rate * gamma)
        mean = mean_trial / (1.0 + bulk_rate * gamma)
        f = math.sqrt(q * q + alpha * alpha * mean * mean)
        dpeeq = 2.0 * beta * gamma * f
        p = peeq + dpeeq
        plateau = a + b * pm.pow(p, n)
        rate = dpeeq / dt
        rate_factor = 1.0 + c * pm.log(rate / rate0) if rate > rate0 else 1.0
        densify = pm.pow(eps_d / (eps_d - p), exp_d) / coef_d if p < eps_d else math.inf
        densify_factor = max(1.0, densify)
        capped = plateau * rate_factor * densify_factor >= cap
        g = f - beta * (cap if capped else plateau * rate_factor * densify_factor)
        if abs(g) <= _RETURN_TOLERANCE * f_trial:
            return gamma, dpeeq
        if g > 0.0:
            z_lo = z
        else:
            z_hi = z
        if z_hi - z_lo <= _RETURN_TOLERANCE:
            break
        # dg/dz = Δγ·(df/dΔγ − β·dσ_c/dΔε̂ · dΔε̂/dΔγ)
        df = -(shear_rate * q * q / (1.0 + shear_rate * gamma) + bulk_rate * alpha * alpha * mean * mean / (1.0 + bulk_rate * gamma)) / f
        dx = 2.0 * beta * (f + gamma * df)
        dsigma = 0.0 if capped else b * n * pm.pow(p, n - 1.0) * rate_factor * densify_factor
        if densify > 1.0 and not capped:
            dsigma += plateau * rate_factor * exp_d * densify_factor / (eps_d - p)
        if rate > rate0 and not capped:
            dsigma += plateau * densify_factor * c / dpeeq
        newton = z - g / (gamma * (df - beta * dsigma * dx))
        z = newton if z_lo < newton < z_hi else 0.5 * (z_lo + z_hi)
    return gamma, dpeeq
