"""The reamer-advance regressor: grid search over four kinds, plain-array export equal to scikit-learn."""

from __future__ import annotations

import numpy as np
import pytest

from thrsim.learn.advance import KINDS, ArrayRegressor, _candidates, export, fit_advance


def _data(n=120, seed=0):
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.normal(0, 1, (n, 3)), rng.uniform(0, 20, n), rng.choice([0, 15, 30], n), rng.uniform(0, 180, n), rng.choice([150, 230, 310], n)])
    y = 0.01 * X[:, 3] + 0.002 * X[:, 4] + 0.0005 * X[:, 6] + rng.normal(0, 0.01, n)
    return X, y


@pytest.mark.parametrize("kind", KINDS)
def test_exported_arrays_predict_like_scikit_learn(kind):
    X, y = _data()
    estimator, _ = _candidates(0, trees=20)[kind]
    estimator.fit(X, y)
    exported = export(kind, estimator)
    assert all(isinstance(v, np.ndarray) and v.dtype != object for v in exported.arrays.values())
    fresh = ArrayRegressor(kind, {k: v.copy() for k, v in exported.arrays.items()})
    X_new, _ = _data(40, seed=1)
    expected = estimator.predict(X_new)
    # same leaves / coefficients; only the order of the final sums may differ
    assert np.allclose(fresh.predict(X_new), expected, rtol=1e-12, atol=1e-14)


def test_grid_search_tables_every_kind_and_keeps_the_lowest_cross_validated_error():
    X, y = _data()
    groups = np.repeat(np.arange(6), 20)
    held_X, held_y = _data(30, seed=2)
    regressor, table = fit_advance(X, y, groups, held_X, held_y, trees=10)
    assert set(table["models"]) == set(KINDS)
    best = min(table["models"], key=lambda k: table["models"][k]["cv_mse_mm2"])
    assert table["chosen"] == best == regressor.kind
    for row in table["models"].values():
        assert row["held_out_samples"] == 30 and row["held_out_mae_mm"] >= 0
    # a linear truth: the linear kinds fit it far better than a constant
    assert table["models"]["linear"]["held_out_mse_mm2"] < 0.2 * np.var(held_y)


def test_unknown_kind_is_refused():
    with pytest.raises(ValueError):
        ArrayRegressor("knn", {})
