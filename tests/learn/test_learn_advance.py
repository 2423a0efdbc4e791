"""The reamer-advance regressor: grid search over four kinds, plain-array export equal to scikit-learn,
predictions clipped to the training targets, the advance learned scaled to a reference push."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from safetensors.numpy import load_file, save_file

from thrsim.learn.advance import FEATURES, KINDS, ArrayRegressor, _candidates, case_samples, export, fit_advance


def _data(n=120, seed=0):
    rng = np.random.default_rng(seed)
    X = np.column_stack(
        [rng.uniform(0, 3, n), rng.choice([0, 15, 30], n), rng.uniform(0, 180, n), rng.choice([150, 230, 310], n), rng.uniform(0, 460, n)]
    )
    y = 0.01 * X[:, 0] + 0.002 * X[:, 1] + 0.0005 * X[:, 3] + 1e-4 * X[:, 4] + rng.normal(0, 0.01, n)
    return X, y


@pytest.mark.parametrize("kind", KINDS)
def test_exported_arrays_predict_like_scikit_learn_after_a_safetensors_round_trip(kind, tmp_path):
    X, y = _data()
    estimator, _ = _candidates(0, trees=20)[kind]
    estimator.fit(X, y)
    exported = export(kind, estimator, (-np.inf, np.inf), reference_force_n=None)
    assert all(isinstance(v, np.ndarray) and v.dtype != object for v in exported.arrays.values())
    save_file({k: np.ascontiguousarray(v) for k, v in exported.arrays.items()}, str(tmp_path / "advance.safetensors"))
    fresh = ArrayRegressor(kind, load_file(str(tmp_path / "advance.safetensors")))
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


@pytest.mark.parametrize("kind", ("linear", "random_forest"))
def test_predictions_stay_within_the_advances_seen_in_training(kind):
    X, y = _data()
    estimator, _ = _candidates(0, trees=20)[kind]
    estimator.fit(X, y)
    regressor = export(kind, estimator, (float(y.min()), float(y.max())), reference_force_n=None)
    far = X[:5].copy()
    far[:, 0] = [-1e3, -50, 0, 200, 1e4]  # depths far outside the data
    predicted = regressor.predict(far)
    assert (predicted >= y.min()).all() and (predicted <= y.max()).all()
    # the linear kind would leave the range without the clip: the clip is what holds it
    if kind == "linear":
        unclipped = estimator.predict(far)
        assert unclipped.max() > y.max() and unclipped.min() < y.min()


def test_the_advance_is_learned_per_unit_push_so_the_push_carries_it_to_other_forces():
    """Truth: advance = push × a function of depth. Fitted on 150 and 230 N only, the regressor
    (scaled to 230 N, then back by the push) predicts 310 N; a forest of the advance itself cannot
    exceed 230 N's."""
    rng = np.random.default_rng(4)
    n = 240
    X = np.column_stack(
        [rng.uniform(0, 3, n), np.full(n, 15.0), rng.uniform(0, 180, n), rng.choice([150.0, 230.0], n), rng.uniform(0, 460, n)]
    )

    def truth(X: np.ndarray) -> np.ndarray:
        return X[:, 3] * (4e-4 + 2e-4 * np.sin(X[:, 0]))

    regressor, table = fit_advance(X, truth(X), np.repeat(np.arange(6), 40), None, None, trees=20)
    assert regressor.reference_force_n == 230.0 and "230 N / push" in table["target"]
    at_310 = X[:40].copy()
    at_310[:, 3] = 310.0
    assert np.abs(regressor.predict(at_310) - truth(at_310)).max() < 0.1 * truth(at_310).min()
    assert regressor.predict(at_310).max() > 1.2 * truth(X).max()  # beyond every advance seen in training


def test_rows_carry_the_push_impulse_and_a_four_feature_regressor_reads_four():
    positions = np.array([[0.0, 0.0, -z] for z in (0.0, 1e-4, 3e-4, 4e-4)])
    case = SimpleNamespace(
        frames=4,
        positions=positions,
        axis=np.array([0.0, 0.0, -1.0]),
        inclination_deg=0.0,
        anteversion_deg=0.0,
        force_n=240.0,
        frame_dt_s=1 / 60,
        advances=lambda: np.diff(positions, axis=0) @ [0.0, 0.0, -1.0],
    )
    X, y = case_samples(case)
    assert X.shape == (3, len(FEATURES)) and np.allclose(X[:, 4], [0.0, 4.0, 8.0])
    assert np.allclose(X[:, 0], [0.0, 0.1, 0.3]) and np.allclose(y, [0.1, 0.2, 0.1])
    old = ArrayRegressor(
        "linear",
        {
            "mean": np.zeros(4),
            "scale": np.ones(4),
            "coef": np.array([1.0, 0.0, 0.0, 0.0]),
            "intercept": np.array(0.0),
            "target_range": np.array([-9.0, 9.0]),
        },
    )
    assert old.n_features == 4 and old.reference_force_n is None and np.allclose(old.predict(X), X[:, 0])


def test_unknown_kind_is_refused():
    with pytest.raises(ValueError):
        ArrayRegressor("knn", {})
