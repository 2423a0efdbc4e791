"""Fixtures shared across test folders: a synthetic dataset and a tiny model trained on it.

The learned-simulator tests (tests/learn) and the reaming trainer's (tests/app) both need a real
trained model (a patch model, and a whole-socket one); each is trained once per test session (a 192-tet synthetic block, 12 frames per case,
networks a few units wide).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings
from learn_helpers import run_thrsim, tiny_settings, tiny_socket_settings

# Property tests draw the same examples on every run and have no per-example time limit: a loaded
# 2-core CI machine must not fail a correct example for its speed (speed lives in `thrsim bench`),
# and a failure must reproduce on the next run rather than depend on that run's random draw.
settings.register_profile("thrsim", deadline=None, derandomize=True)
settings.load_profile("thrsim")


@pytest.fixture(scope="session")
def synthetic_dataset(tmp_path_factory) -> Path:
    """Synthetic sweep: γ 0, 15, 30 × θ 0 (train), 45 (test), 90 (validation); 12 frames, 192 tets."""
    out = tmp_path_factory.mktemp("learn-data") / "synthetic"
    result = run_thrsim(
        "dataset",
        "--solver",
        "synthetic",
        "--out",
        str(out),
        "--inclinations",
        "0,15,30",
        "--anteversions",
        "0,45,90",
        "--frames",
        "12",
        "--element-sizes",
        "1.0",
        "--extra-forces",
        "none",
        "--json",
    )
    assert result.returncode == 0, result.stderr
    return out


def _trained(data: Path, folder: Path, settings) -> Path:
    """A model trained on ``data`` with ``settings`` into ``folder``/model, on one thread."""
    import torch

    from thrsim.learn.pipeline import train_model

    torch.set_num_threads(1)
    train_model(data, folder / "model", settings)
    return folder / "model"


@pytest.fixture(scope="session")
def tiny_model(synthetic_dataset, tmp_path_factory) -> Path:
    return _trained(synthetic_dataset, tmp_path_factory.mktemp("learn-model"), tiny_settings())


@pytest.fixture(scope="session")
def tiny_socket_model(synthetic_dataset, tmp_path_factory) -> Path:
    """A whole-socket model (the socket features and reaction head) trained as :func:`tiny_model` is."""
    return _trained(synthetic_dataset, tmp_path_factory.mktemp("learn-socket-model"), tiny_socket_settings())


@pytest.fixture(scope="session")
def tiny_prior_socket_model(synthetic_dataset, tmp_path_factory) -> Path:
    """As :func:`tiny_socket_model`, its reaction law weighted by the cutting prior."""
    return _trained(synthetic_dataset, tmp_path_factory.mktemp("learn-prior-model"), tiny_socket_settings(reaction_prior="cutting"))
