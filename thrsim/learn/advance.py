"""The reamer-advance regressor [7.3.4, eq. 50]: how far the reamer moves along D in the next frame.

Δposition = Φ(depth, γ, θ, push force, push impulse): the depth along D from where the reamer was
placed instead of eq. 50's absolute position and removed count (both made autonomous rollouts
unstable), the push impulse Σ F·Δt as the cutting work so far, the target scaled to a reference
push and back. Predictions are clipped to the advances seen in training. Four scikit-learn models
are compared by grid search with cross-validation grouped by case (Random Forest, SVR, Ridge,
linear); the winner is stored as plain arrays and evaluated by :class:`ArrayRegressor`, so loading
never unpickles. Regressors stored before the impulse (four features) or the scaling (no
``reference_force_n``) are read as such. Why each choice, with its measurements: docs,
"Benchmarks and validation", "Design measurements".
"""

from __future__ import annotations

from typing import Literal, get_args

import numpy as np

from thrsim.config import PUSH_FORCE_N

FEATURES = ("depth_mm", "inclination_deg", "anteversion_deg", "force_n", "impulse_n_s")
Kind = Literal["random_forest", "svr", "ridge", "linear"]
KINDS: tuple[Kind, ...] = get_args(Kind)
#: choose the kind with the lowest cross-validated error of one frame's advance
LOWEST_CV = "lowest_cv"
#: the arrays each kind's prediction reads (besides target_range)
_KIND_ARRAYS = {
    "random_forest": ("left", "right", "feature", "threshold", "value", "roots"),
    "svr": ("mean", "scale", "support_vectors", "dual_coef", "intercept", "gamma"),
    "ridge": ("mean", "scale", "coef", "intercept"),
    "linear": ("mean", "scale", "coef", "intercept"),
}


def case_samples(case) -> tuple[np.ndarray, np.ndarray]:
    """(X, y) of one case: one row per frame t ≥ 0 with a successor; y = advance t → t+1 in mm."""
    t = np.arange(case.frames - 1)
    depth = (case.positions - case.positions[0]) @ case.axis
    rows = np.column_stack(
        [
            depth[t] * 1e3,
            np.full(len(t), case.inclination_deg),
            np.full(len(t), case.anteversion_deg),
            np.full(len(t), case.force_n),
            case.force_n * case.frame_dt_s * t,
        ]
    )
    return rows, case.advances() * 1e3


def feature_row(depth_m: float, inclination_deg: float, anteversion_deg: float, force_n: float, impulse_n_s: float) -> np.ndarray:
    return np.array([[depth_m * 1e3, inclination_deg, anteversion_deg, force_n, impulse_n_s]])


class ArrayRegressor:
    """A fitted regressor as named arrays (``kind`` one of KINDS) with a NumPy ``predict``."""

    def __init__(self, kind: str, arrays: dict[str, np.ndarray]):
        if kind not in KINDS:
            raise ValueError(f"unknown regressor kind {kind!r} (known: {', '.join(KINDS)})")
        self.kind = kind
        self.arrays = {k: np.asarray(v) for k, v in arrays.items()}
        self._check()

    def _check(self) -> None:
        """ValueError unless the arrays make a regressor that predicts finite advances and ends:
        every array the kind reads, numeric and finite, of consistent shapes; tree nodes that
        point only to later nodes of the table (scikit-learn's order), so no walk leaves the table
        or runs in a circle."""
        a = self.arrays
        needed = ("target_range", *_KIND_ARRAYS[self.kind])
        missing = [name for name in needed if name not in a]
        if missing:
            raise ValueError(f"the {self.kind} regressor lacks array(s) {', '.join(missing)}")
        for name, values in a.items():
            # an unbounded target range (±∞) is allowed: it means "do not clip"
            finite = np.isfinite(values).all() if name != "target_range" else not np.isnan(values).any()
            if values.dtype.kind not in "fiu" or (values.dtype.kind == "f" and not finite):
                raise ValueError(f"regressor array {name!r} ({values.dtype}) is not all finite numbers")
        for name in ("n_features", "reference_force_n", "intercept", "gamma"):
            if name in a and a[name].size != 1:
                raise ValueError(f"regressor array {name!r} has shape {a[name].shape}, expected one value")
        low_high = a["target_range"]
        if low_high.shape != (2,) or low_high[0] > low_high[1]:
            raise ValueError(f"regressor target_range {low_high.tolist()} is not [low, high]")
        if self.n_features not in (len(FEATURES) - 1, len(FEATURES)):
            raise ValueError(f"regressor n_features {self.n_features}, expected {len(FEATURES) - 1} or {len(FEATURES)}")
        if self.reference_force_n is not None and not self.reference_force_n > 0:
            raise ValueError(f"regressor reference_force_n {self.reference_force_n} is not a positive push")
        if self.kind == "random_forest":
            self._check_forest()
            return
        width = (self.n_features,)
        shapes: dict[str, tuple[int, ...]] = {
            "mean": width,
            "scale": width,
            **({"coef": width} if "coef" in _KIND_ARRAYS[self.kind] else {}),
        }
        if self.kind == "svr":
            shapes.update(support_vectors=(len(a["dual_coef"]), self.n_features), dual_coef=(len(a["dual_coef"]),))
        for name, shape in shapes.items():
            if a[name].shape != shape:
                raise ValueError(f"regressor array {name!r} has shape {a[name].shape}, expected {shape}")
        if not np.all(a["scale"] != 0):
            raise ValueError("regressor array 'scale' holds a zero")

    def _check_forest(self) -> None:
        a = self.arrays
        n = len(a["left"])
        for name in ("left", "right", "feature", "threshold", "value"):
            if a[name].shape != (n,) or n == 0:
                raise ValueError(f"forest array {name!r} has shape {a[name].shape}, expected ({n},) like 'left' (one per node)")
        for name in ("left", "right", "feature", "roots"):
            if a[name].dtype.kind not in "iu":
                raise ValueError(f"forest array {name!r} has dtype {a[name].dtype}, expected integers")
        roots = a["roots"]
        if roots.ndim != 1 or len(roots) == 0 or roots.min() < 0 or roots.max() >= n:
            raise ValueError(f"forest roots must be node indices in [0, {n}), got {roots.min(initial=0)} to {roots.max(initial=0)}")
        node = np.arange(n)
        split = a["left"] >= 0
        for name in ("left", "right"):
            child = a[name][split].astype(np.int64)
            bad = (child <= node[split]) | (child >= n)
            if bad.any():
                first = int(node[split][bad][0])
                raise ValueError(
                    f"forest node {first}'s {name} child {int(child[bad][0])} is not a later node of the {n} (a cycle or out of range)"
                )
        feature = a["feature"][split]
        if feature.size and (feature.min() < 0 or feature.max() >= self.n_features):
            raise ValueError(f"forest splits on feature {int(feature.max())} (or below 0); the regressor reads {self.n_features}")

    @property
    def reference_force_n(self) -> float | None:
        """The push its targets were scaled to (None: it predicts the advance itself)."""
        stored = self.arrays.get("reference_force_n")
        return None if stored is None else float(np.ravel(stored)[0])

    @property
    def n_features(self) -> int:
        stored = self.arrays.get("n_features")
        return len(FEATURES) - 1 if stored is None else int(np.ravel(stored)[0])  # stored before the impulse existed

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Advance in mm, clipped to the range of the training targets (rows of :data:`FEATURES`;
        a regressor of the first four reads those only)."""
        low, high = self.arrays["target_range"]
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))[:, : self.n_features]
        advance = np.clip(self._raw(X), low, high)
        if self.reference_force_n is None:
            return advance
        return advance * X[:, FEATURES.index("force_n")] / self.reference_force_n

    def _raw(self, X: np.ndarray) -> np.ndarray:
        a = self.arrays
        if self.kind == "random_forest":
            return self._forest(X)
        Z = (X - a["mean"]) / a["scale"]
        if self.kind == "svr":
            d2 = ((Z[:, None, :] - a["support_vectors"][None, :, :]) ** 2).sum(axis=2)
            return np.exp(-a["gamma"].item() * d2) @ a["dual_coef"] + a["intercept"].item()
        return Z @ a["coef"] + a["intercept"].item()

    def _forest(self, X: np.ndarray) -> np.ndarray:
        a = self.arrays
        # scikit-learn's trees compare float32 inputs against float64 thresholds
        X = X.astype(np.float32).astype(np.float64)
        left, right, feature, threshold, value = a["left"], a["right"], a["feature"], a["threshold"], a["value"]
        rows = np.arange(len(X))[:, None]
        index = np.broadcast_to(a["roots"], (len(X), len(a["roots"]))).copy()
        while True:
            leaf = left[index] < 0
            if leaf.all():
                break
            go_left = X[rows, np.maximum(feature[index], 0)] <= threshold[index]
            index = np.where(leaf, index, np.where(go_left, left[index], right[index]))
        return value[index].mean(axis=1)


def export(kind: str, estimator, target_range: tuple[float, float], *, reference_force_n: float | None) -> ArrayRegressor:
    """Plain arrays of a fitted scikit-learn estimator (a Pipeline for the scaled kinds) that
    predicts the advance (scaled to ``reference_force_n`` of push, if given) in ``target_range``."""
    bounds = {"target_range": np.array(target_range, dtype=np.float64), "n_features": np.array(estimator.n_features_in_)}
    if reference_force_n is not None:
        bounds["reference_force_n"] = np.array(float(reference_force_n))
    if kind == "random_forest":
        parts: dict[str, list] = {k: [] for k in ("left", "right", "feature", "threshold", "value")}
        roots, offset = [], 0
        for tree in estimator.estimators_:
            t = tree.tree_
            roots.append(offset)
            for name, child in (("left", t.children_left), ("right", t.children_right)):
                parts[name].append(np.where(child >= 0, child + offset, -1))
            parts["feature"].append(t.feature)
            parts["threshold"].append(t.threshold)
            parts["value"].append(t.value[:, 0, 0])
            offset += t.node_count
        arrays = {k: np.concatenate(v) for k, v in parts.items()}
        arrays["roots"] = np.array(roots, dtype=np.int64)
        for k in ("left", "right", "feature"):
            arrays[k] = arrays[k].astype(np.int32)
        return ArrayRegressor(kind, {**arrays, **bounds})
    scaler, model = estimator.named_steps["scale"], estimator.named_steps["model"]
    arrays = {"mean": scaler.mean_, "scale": scaler.scale_}
    if kind == "svr":
        arrays.update(
            support_vectors=model.support_vectors_,
            dual_coef=model.dual_coef_[0],
            intercept=np.array(model.intercept_[0]),
            gamma=np.array(model._gamma),
        )
    else:
        arrays.update(coef=np.asarray(model.coef_, dtype=np.float64).reshape(-1), intercept=np.array(float(np.ravel(model.intercept_)[0])))
    return ArrayRegressor(kind, {**arrays, **bounds})


def _candidates(seed: int, trees: int = 100) -> dict:
    from sklearn.ensemble import RandomForestRegressor
    from sklearn.linear_model import LinearRegression, Ridge
    from sklearn.pipeline import Pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVR

    def scaled(model):
        return Pipeline([("scale", StandardScaler()), ("model", model)])

    return {
        # depth ≤ 10 bounds the stored forest to 100 × 2,047 nodes (≤ 6 MB) whatever the data size
        "random_forest": (
            RandomForestRegressor(n_estimators=trees, random_state=seed, n_jobs=1),
            {"max_depth": [6, 10], "min_samples_leaf": [1, 5]},
        ),
        "svr": (scaled(SVR(kernel="rbf")), {"model__C": [0.1, 1.0, 10.0], "model__epsilon": [0.005, 0.05]}),
        "ridge": (scaled(Ridge()), {"model__alpha": [0.1, 1.0, 10.0]}),
        "linear": (scaled(LinearRegression()), {}),
    }


#: the push the regressor's targets are scaled to (the dataset's default; a model's regressor keeps
#: the value it was trained with, the thesis's mean push, which is not a setting to change)
REFERENCE_FORCE_N = PUSH_FORCE_N


def _push_scale(X: np.ndarray) -> np.ndarray:
    return X[:, FEATURES.index("force_n")] / REFERENCE_FORCE_N


def _mse_of_advance(estimator, X: np.ndarray, y_scaled: np.ndarray) -> float:
    """Scorer: minus the mean squared error of the advance itself (mm²), not of its scaled form."""
    return -float(np.mean(((estimator.predict(X) - y_scaled) * _push_scale(X)) ** 2))


def fit_advance(
    X: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    held_X: np.ndarray | None,
    held_y: np.ndarray | None,
    seed: int = 0,
    trees: int = 100,
    keep: str = LOWEST_CV,
) -> tuple[ArrayRegressor, dict]:
    """Grid-search the four kinds on the advance scaled to the reference push and keep ``keep``, or
    with :data:`LOWEST_CV` the lowest cross-validated MSE of the advance; (regressor, error table)."""
    from sklearn.model_selection import GridSearchCV, GroupKFold, KFold

    n_groups = len(np.unique(groups))
    folds = GroupKFold(n_splits=min(3, n_groups)) if n_groups >= 2 else KFold(n_splits=min(3, len(y)), shuffle=True, random_state=seed)
    y_scaled = y / _push_scale(X)
    target_range = (float(y_scaled.min()), float(y_scaled.max()))
    table: dict[str, dict] = {}
    exported = {}
    for kind, (estimator, grid) in _candidates(seed, trees).items():
        search = GridSearchCV(estimator, grid or {}, cv=folds, scoring=_mse_of_advance, n_jobs=1)
        search.fit(X, y_scaled, groups=groups if n_groups >= 2 else None)
        exported[kind] = export(kind, search.best_estimator_, target_range, reference_force_n=REFERENCE_FORCE_N)
        row = {
            "cv_mse_mm2": float(-search.best_score_),
            "best_params": {k.replace("model__", ""): v for k, v in search.best_params_.items()},
        }
        if held_X is not None and held_y is not None and len(held_y):
            error = exported[kind].predict(held_X) - held_y
            row.update(
                held_out_mse_mm2=float(np.mean(error**2)), held_out_mae_mm=float(np.mean(np.abs(error))), held_out_samples=int(len(held_y))
            )
        table[kind] = row
    chosen = min(table, key=lambda k: table[k]["cv_mse_mm2"]) if keep == LOWEST_CV else keep
    return exported[chosen], {
        "chosen": chosen,
        "chosen_by": "lowest cross-validated error" if keep == LOWEST_CV else "the training settings' advance_kind",
        "features": list(FEATURES),
        "target": f"advance along D per frame, mm, learned × {REFERENCE_FORCE_N:g} N / push and scaled back",
        "models": table,
    }
