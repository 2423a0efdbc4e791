"""exp, log, pow, sin, cos, atan2 and cbrt from + − × ÷ and √ only: the same bits on every x86-64.

glibc picks its libm at run time by CPU (FMA, AVX2, AVX-512 variants) and NumPy dispatches its
own SIMD loops the same way; each variant is accurate to about an ulp but they disagree in the
last bit, and a reaming trajectory turns one ulp into a different cut within a few frames. So
every transcendental function that feeds the solver state is computed here from IEEE-754 basic
operations (correctly rounded, never fused: Numba compiles without fast-math), in a fixed order,
accurate to a few ulp over the solver's ranges (the tests check against the C library). Range
reductions follow Cody & Waite (ln 2 and π/2 split so that k·c_hi is exact); the kernels are
Taylor series truncated below 1e-17 relative on the reduced interval.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from thrsim.cache import use_numba_cache

use_numba_cache()  # before the first kernel: Numba reads the cache folder then

_LN2_HI = 6.93147180369123816490e-01  # ln 2 with its last 32 bits zero: k·_LN2_HI is exact
_LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e00
_PIO2_1 = 1.57079632673412561417e00  # π/2 in three parts (fdlibm's), the first two with zero tails
_PIO2_2 = 6.07710050630396597660e-11
_PIO2_3 = 2.02226624879595063154e-21
_INV_PIO2 = 6.36619772367581382433e-01
_PI = 3.14159265358979311600e00
_PIO2 = 1.57079632679489655800e00
_PIO4 = 7.85398163397448278999e-01
_SQRT_HALF = 7.07106781186547524401e-01


# Taylor coefficients, highest order first (Horner): 1/k! for exp on |r| ≤ ln2/2 (k ≤ 13),
# 1/(2k+1) for log's atanh series on |f| ≤ 0.1716 (k ≤ 11), (−1)^k/(2k+1)! and (−1)^k/(2k)! for
# sin and cos on |r| ≤ π/4 (k ≤ 8), (−1)^k/(2k+1) for atan on |t| ≤ 0.2 (k ≤ 12)
_EXP = tuple(1.0 / math.factorial(k) for k in range(13, -1, -1))
_LOG = tuple(1.0 / (2 * k + 1) for k in range(11, 0, -1))
_SIN = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(8, 0, -1))
_COS = tuple((-1.0) ** k / math.factorial(2 * k) for k in range(8, 0, -1))
_ATAN = tuple((-1.0) ** k / (2 * k + 1) for k in range(12, 0, -1))


@njit(cache=True, inline="always")
def _horner(coefficients, x: float) -> float:
    total = 0.0
    for c in coefficients:
        total = total * x + c
    return total


@njit(cache=True, inline="always")
def exp(x: float) -> float:
    if x != x:
        return x
    if x > 709.782712893384:
        return math.inf
    if x < -745.1332191019412:
        return 0.0
    k = math.floor(x * _INV_LN2 + 0.5)
    r = (x - k * _LN2_HI) - k * _LN2_LO  # |r| ≤ ln2/2
    # scale by 2^k in two exact halves so that neither overflows nor underflows early
    half = int(k) // 2
    return math.ldexp(math.ldexp(_horner(_EXP, r), half), int(k) - half)


@njit(cache=True, inline="always")
def log(x: float) -> float:
    if x != x or x < 0.0:
        return math.nan
    if x == 0.0:
        return -math.inf
    if x == math.inf:
        return x
    mantissa, exponent = math.frexp(x)  # exact: x = mantissa · 2^exponent, mantissa in [0.5, 1)
    if mantissa < _SQRT_HALF:
        mantissa *= 2.0
        exponent -= 1
    f = (mantissa - 1.0) / (mantissa + 1.0)  # log m = 2 atanh f = 2f (1 + f²/3 + f⁴/5 + …)
    s = f * f
    log_mantissa = 2.0 * f + 2.0 * f * (s * _horner(_LOG, s))
    return exponent * _LN2_HI + (exponent * _LN2_LO + log_mantissa)


@njit(cache=True, inline="always")
def pow(x: float, y: float) -> float:
    """x^y for x ≥ 0 (the solver raises only non-negative strains to powers)."""
    if y == 0.0:
        return 1.0
    if x == 0.0:
        return 0.0 if y > 0.0 else math.inf
    return exp(y * log(x))


@njit(cache=True, inline="always")
def _reduce_quadrant(x: float):
    k = math.floor(x * _INV_PIO2 + 0.5)
    r = ((x - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3  # |r| ≤ π/4 for |x| up to ~1e9
    return r, int(k) & 3


@njit(cache=True, inline="always")
def _sin_reduced(r: float) -> float:
    s = r * r
    return r + r * (s * _horner(_SIN, s))


@njit(cache=True, inline="always")
def _cos_reduced(r: float) -> float:
    s = r * r
    return 1.0 + s * _horner(_COS, s)


@njit(cache=True, inline="always")
def sin(x: float) -> float:
    r, quadrant = _reduce_quadrant(x)
    if quadrant == 0:
        return _sin_reduced(r)
    if quadrant == 1:
        return _cos_reduced(r)
    if quadrant == 2:
        return -_sin_reduced(r)
    return -_cos_reduced(r)


@njit(cache=True, inline="always")
def cos(x: float) -> float:
    r, quadrant = _reduce_quadrant(x)
    if quadrant == 0:
        return _cos_reduced(r)
    if quadrant == 1:
        return -_sin_reduced(r)
    if quadrant == 2:
        return -_cos_reduced(r)
    return _sin_reduced(r)


@njit(cache=True, inline="always")
def _atan_unit(t: float) -> float:
    """atan(t) for 0 ≤ t ≤ 1."""
    offset = 0.0
    if t > 0.4142135623730950:  # tan(π/8): atan t = π/4 + atan((t−1)/(t+1))
        t = (t - 1.0) / (t + 1.0)
        offset = _PIO4
    # halve once more: atan t = 2 atan(t / (1 + √(1+t²))), |t| ≤ 0.2
    t = t / (1.0 + math.sqrt(1.0 + t * t))
    s = t * t
    return offset + 2.0 * (t + t * (s * _horner(_ATAN, s)))


@njit(cache=True, inline="always")
def atan2(y: float, x: float) -> float:
    if y != y or x != x:
        return math.nan
    ay, ax = abs(y), abs(x)
    if ay == 0.0 and ax == 0.0:
        angle = 0.0
    elif ay <= ax:
        angle = _atan_unit(ay / ax)
    else:
        angle = _PIO2 - _atan_unit(ax / ay)
    if math.copysign(1.0, x) < 0.0:  # x = −0 counts as negative, as in C
        angle = _PI - angle
    return math.copysign(angle, y)  # signed zeros as in C: atan2(−0, −1) = −π


@njit(cache=True, inline="always")
def cbrt(x: float) -> float:
    if x == 0.0 or x != x:
        return x
    a = abs(x)
    root = exp(log(a) / 3.0)
    root = root - (root * root * root - a) / (3.0 * root * root)  # one Newton step: a few ulp
    return root if x > 0.0 else -root


@njit(cache=True)
def sin_array(x: np.ndarray) -> np.ndarray:
    out = np.empty_like(x)
    for i in range(x.size):
        out.flat[i] = sin(x.flat[i])
    return out


@njit(cache=True)
def cos_array(x: np.ndarray) -> np.ndarray:
    out = np.empty_like(x)
    for i in range(x.size):
        out.flat[i] = cos(x.flat[i])
    return out


@njit(cache=True)
def cbrt_array(x: np.ndarray) -> np.ndarray:
    out = np.empty_like(x)
    for i in range(x.size):
        out.flat[i] = cbrt(x.flat[i])
    return out
