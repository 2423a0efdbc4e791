"""Helpers of the learned-simulator tests: this checkout's thrsim as a subprocess, tiny settings."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from thrsim.learn.settings import ArchSettings, ModelSettings, TrainSettings, preset

REPO = Path(__file__).resolve().parents[1]


def run_thrsim(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """This checkout's thrsim, as a user runs it (``python -m thrsim``), one numerical thread."""
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "thrsim", *args], cwd=REPO, capture_output=True, text=True, timeout=timeout, env=env)


def tiny_settings(epochs: int = 2, **train) -> ModelSettings:
    """Networks a few units wide, a handful of samples per epoch; features as the production preset."""
    arch = ArchSettings(
        node_encoder=(8,),
        node_core=(8,),
        node_decoder=(8,),
        edge_encoder=(8,),
        edge_core=(8,),
        global_encoder=(4,),
        message_passing_steps=2,
        mlp_baseline=(8,),
    )
    options = {
        "epochs": epochs,
        "batch_size": 2,
        "max_samples_per_epoch": 8,
        "normaliser_samples": 8,
        "validation_horizon": 4,
        "advance_trees": 5,
        **train,
    }
    return ModelSettings(arch=arch, features=preset("production").features, train=TrainSettings(**options))


def tiny_socket_settings(epochs: int = 3, reaction_prior: str = "none", **train) -> ModelSettings:
    """As :func:`tiny_settings`, with the socket preset's features and its reaction head (and its prior)."""
    tiny = tiny_settings(epochs, **train)
    return ModelSettings(
        arch=tiny.arch.model_copy(update={"reaction_head": True, "removal_head": True, "reaction_prior": reaction_prior}),
        features=preset("socket").features,
        train=tiny.train,
    )


def use_forest_regressor(model: Path) -> None:
    """Give a copied model folder a small random-forest feed regressor in place of its own, so that
    the validation tests can spoil a forest's trees (the shipped patch model's feed is an SVR)."""
    import json

    import numpy as np
    from sklearn.ensemble import RandomForestRegressor

    from thrsim.learn.advance import FEATURES, REFERENCE_FORCE_N, export
    from thrsim.learn.model_dir import CARD, save_advance

    rng = np.random.default_rng(0)
    X = rng.uniform(0.0, 1.0, (200, len(FEATURES)))
    forest = RandomForestRegressor(n_estimators=4, max_depth=5, random_state=0).fit(X, 0.05 * X[:, 0])
    card = json.loads((model / CARD).read_text())
    save_advance(model, card, export("random_forest", forest, (0.0, 0.05), reference_force_n=REFERENCE_FORCE_N))
