"""Shared data for the learned-simulator tests: one real solver case, the tiny settings as a file.

Small: a 2 mm-element solver case of 6 frames; networks a few units wide. The synthetic dataset
and the tiny model trained on it are shared with other folders (tests/conftest.py).
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
def real_case(tmp_path_factory) -> Path:
    """One case of the real explicit solver on a 2 mm mesh (438 tets), 6 frames at γ 30°."""
    out = tmp_path_factory.mktemp("learn-real") / "g30.h5"
    result = run_thrsim(
        "fem",
        "--inclination",
        "30",
        "--anteversion",
        "0",
        "--frames",
        "6",
        "--element-size",
        "2.0",
        "--threads",
        "1",
        "--out",
        str(out),
        "--json",
    )
    assert result.returncode == 0, result.stderr
    return out


@pytest.fixture
def settings_file(tmp_path) -> Path:
    """The tiny settings as a ``thrsim train --settings`` file."""
    s = tiny_settings(epochs=1).model_dump(mode="json")
    path = tmp_path / "tiny.json"
    path.write_text(json.dumps({"arch": s["arch"], "train": s["train"]}))
    return path
