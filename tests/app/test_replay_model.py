"""``thrsim replay`` never loads the model folder a session file names by itself (issue 27, item 5):
a session reamed with another folder than the shipped model needs ``--model``, and the folder
given passes the same checks as any model."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest
from checkout_cli import run_main
from safetensors.numpy import load_file, save_file

from thrsim.app.live import LiveSession
from thrsim.app.modes import MODES
from thrsim.learn.model_dir import ADVANCE, SHIPPED_MODEL

pytestmark = pytest.mark.timeout(180)
STEP = 1 / 60


@pytest.fixture(scope="module")
def session_naming_a_folder(tmp_path_factory):
    """A short reaming session whose settings name a model folder elsewhere (a copy of the shipped one)."""
    folder = tmp_path_factory.mktemp("replay-model")
    elsewhere = folder / "elsewhere"
    shutil.copytree(SHIPPED_MODEL, elsewhere)
    now = [0.0]
    live = LiveSession(MODES["reaming"], {"side": "right", "seed": 5}, lambda: now[0], folder)
    live.control('{"type": "run", "action": "start"}')
    for _ in range(6):
        now[0] += STEP
        live.tick()
    path = live.save(folder)
    with h5py.File(path, "r+") as f:
        settings = json.loads(f.attrs["settings"])
        f.attrs["settings"] = json.dumps({**settings, "model": str(elsewhere)})
    return path, elsewhere


def test_a_session_naming_another_model_folder_needs_model(session_naming_a_folder, monkeypatch, capsys):
    path, elsewhere = session_naming_a_folder
    code, out, err = run_main(monkeypatch, capsys, "replay", str(path), "--json")
    assert code == 2 and out == "", (code, out, err)
    assert len(err.splitlines()) == 1 and err.startswith("thrsim: error: ") and "--model" in err and str(elsewhere) in err


def test_the_named_model_is_used_and_reported(session_naming_a_folder, monkeypatch, capsys):
    path, elsewhere = session_naming_a_folder
    code, out, err = run_main(monkeypatch, capsys, "replay", str(path), "--model", str(elsewhere), "--json")
    assert code == 0, err
    outcome = json.loads(out)
    assert outcome["reproduced"] is True and outcome["model"] == str(elsewhere)


def test_a_named_model_that_fails_its_checks_is_refused(session_naming_a_folder, tmp_path, monkeypatch, capsys):
    path, _ = session_naming_a_folder
    spoiled = tmp_path / "spoiled"
    shutil.copytree(SHIPPED_MODEL, spoiled)
    arrays = load_file(str(spoiled / ADVANCE))
    arrays["dual_coef"][0] = np.nan  # the shipped patch model's feed is an SVR
    save_file(arrays, str(spoiled / ADVANCE), metadata={"kind": "svr"})
    code, out, err = run_main(monkeypatch, capsys, "replay", str(path), "--model", str(spoiled))
    assert code == 2 and out == "", (code, out, err)
    assert len(err.splitlines()) == 1 and "advance.safetensors" in err and "'dual_coef'" in err
