"""Shared data for the learned-simulator tests: a synthetic dataset, one real solver case, a tiny trained model.

Everything is small: a 192-tet synthetic block (12 frames per case) and a 2 mm-element solver
case of 6 frames; networks a few units wide. Built once per test session.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from learn_helpers import run_thrsim, tiny_settings


@pytest.fixture(autouse=True, scope="session")
def _one_thread():
    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def synthetic_dataset(tmp_path_factory) -> Path:
    """Synthetic sweep: γ 0, 15, 30 × θ 0 (train), 45 (test), 90 (validation); 12 frames, 192 tets."""
    out = tmp_path_factory.mktemp("learn-data") / "synthetic"
    result = run_thrsim(
        "dataset", "--solver", "synthetic", "--out", str(out), "--inclinations", "0,15,30", "--anteversions", "0,45,90",
        "--frames", "12", "--element-sizes", "1.0", "--extra-forces", "none", "--json",
    )
    assert result.returncode == 0, result.stderr
    return out


@pytest.fixture(scope="session")
def real_case(tmp_path_factory) -> Path:
    """One case of the real explicit solver on a 2 mm mesh (438 tets), 6 frames at γ 30°."""
    out = tmp_path_factory.mktemp("learn-real") / "g30.h5"
    result = run_thrsim("fem", "--inclination", "30", "--anteversion", "0", "--frames", "6", "--element-size", "2.0", "--threads", "1", "--out", str(out), "--json")
    assert result.returncode == 0, result.stderr
    return out


@pytest.fixture(scope="session")
def tiny_model(synthetic_dataset, tmp_path_factory) -> Path:
    from thrsim.learn.pipeline import train_model

    out = tmp_path_factory.mktemp("learn-model") / "model"
    train_model(synthetic_dataset, out, tiny_settings())
    return out


@pytest.fixture
def settings_file(tmp_path) -> Path:
    """The tiny settings as a ``thrsim train --settings`` file."""
    s = tiny_settings(epochs=1).model_dump(mode="json")
    path = tmp_path / "tiny.json"
    path.write_text(json.dumps({"arch": s["arch"], "train": s["train"]}))
    return path
