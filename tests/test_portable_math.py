"""thrsim.portable_math agrees with the C library to a few ulp over the solver's ranges, and
handles the edge values the solver can meet."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from thrsim import portable_math as pm

ULP_LIMIT = 4


def _ulps(got: float, want: float) -> float:
    return abs(got - want) / math.ulp(abs(want)) if want != 0.0 else abs(got) / math.ulp(0.0)


@settings(max_examples=400, deadline=None)
@given(st.floats(-700.0, 700.0))
def test_exp(x):
    assert _ulps(pm.exp(x), math.exp(x)) <= ULP_LIMIT


@settings(max_examples=400, deadline=None)
@given(st.floats(1e-300, 1e300))
def test_log(x):
    assert _ulps(pm.log(x), math.log(x)) <= ULP_LIMIT


@settings(max_examples=400, deadline=None)
@given(st.floats(-2000.0, 2000.0))
def test_sin_and_cos(x):
    # absolute error against 1: near a zero of sin or cos, ulps of the tiny result mean nothing
    assert abs(pm.sin(x) - math.sin(x)) <= ULP_LIMIT * math.ulp(1.0)
    assert abs(pm.cos(x) - math.cos(x)) <= ULP_LIMIT * math.ulp(1.0)


@settings(max_examples=400, deadline=None)
@given(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3))
def test_atan2(y, x):
    assert abs(pm.atan2(y, x) - math.atan2(y, x)) <= ULP_LIMIT * math.ulp(math.pi)


@settings(max_examples=400, deadline=None)
@given(st.floats(0.0, 10.0), st.floats(-1.0, 1.0))
def test_pow_of_non_negative_bases(x, y):
    # exp(y ln x): the rounding of y ln x is magnified by |y ln x|, as in any pow built this way
    # (the solver raises strains ≤ 10 to exponents below 1, where |y ln x| stays small)
    if x == 0.0:
        assert pm.pow(x, y) == (1.0 if y == 0.0 else 0.0 if y > 0.0 else math.inf)
        return
    try:
        want = math.pow(x, y)
    except OverflowError:  # a subnormal base to a negative power: beyond the largest double
        assert pm.pow(x, y) == math.inf
        return
    assert _ulps(pm.pow(x, y), want) <= ULP_LIMIT + 2.0 * abs(y * math.log(x))


def test_cbrt_over_element_volumes():
    volumes = np.geomspace(1e-15, 1e-6, 500)  # tet volumes in m³
    assert np.all(np.abs(pm.cbrt_array(volumes) - np.cbrt(volumes)) <= ULP_LIMIT * np.spacing(np.cbrt(volumes)))


def test_edge_values():
    assert pm.exp(0.0) == 1.0 and pm.log(1.0) == 0.0 and pm.sin(0.0) == 0.0 and pm.cos(0.0) == 1.0
    assert pm.exp(-1000.0) == 0.0 and math.isinf(pm.exp(1000.0))
    assert pm.log(0.0) == -math.inf and math.isnan(pm.log(-1.0)) and math.isnan(pm.exp(math.nan))
    assert pm.atan2(0.0, -1.0) == math.pi and pm.atan2(1.0, 0.0) == math.pi / 2 and pm.atan2(0.0, 0.0) == 0.0
    assert pm.pow(0.0, 0.5) == 0.0 and pm.pow(2.0, 0.0) == 1.0
    assert pm.pow(2.225073858507e-311, -1.0) == math.inf  # found by CI's hypothesis run
    assert pm.cbrt(-8.0) == -2.0 and pm.cbrt(0.0) == 0.0
