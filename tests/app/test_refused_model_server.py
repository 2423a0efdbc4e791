"""``thrsim serve`` with a tampered model folder: it starts, the reaming page says why it cannot
ream, the navigation mode works, and SIGTERM still ends it (issue 27, item 5: a regressor tree
with a cycle used to freeze the server on the first reaming step)."""

from __future__ import annotations

import shutil
import urllib.request

import pytest
from app_helpers import ServedTrainer, next_of_type
from learn_helpers import use_forest_regressor
from safetensors.numpy import load_file, save_file
from websockets.sync.client import connect

from thrsim.learn.model_dir import ADVANCE, SHIPPED_MODEL

pytestmark = pytest.mark.timeout(120)


def test_a_model_with_a_cyclic_regressor_tree_is_refused_and_the_server_lives_on(tmp_path):
    model = tmp_path / "model"
    shutil.copytree(SHIPPED_MODEL, model)
    use_forest_regressor(model)
    arrays = load_file(str(model / ADVANCE))
    root = int(arrays["roots"][0])
    arrays["left"][root] = arrays["right"][root] = root
    save_file(arrays, str(model / ADVANCE), metadata={"kind": "random_forest"})
    sessions = tmp_path / "sessions"
    sessions.mkdir()
    served = ServedTrainer(sessions, "--model", str(model))
    try:
        with connect(f"ws://127.0.0.1:{served.port}/ws/reaming", open_timeout=10) as ws:
            reaming = next_of_type(ws, "hello")["scene"]["reaming"]
            next_of_type(ws, "state")  # the ticker steps the reaming session without hanging
        assert reaming["available"] is False
        assert "advance.safetensors" in reaming["unavailable"] and "cycle" in reaming["unavailable"]
        with urllib.request.urlopen(served.url + "/", timeout=10) as response:
            assert response.status == 200
        with connect(f"ws://127.0.0.1:{served.port}/ws/navigation", open_timeout=10) as ws:
            assert next_of_type(ws, "hello")["mode"] == "navigation"
            next_of_type(ws, "state")
    finally:
        code = served.stop()
    assert code == 0, served.stderr()
    assert "Traceback" not in served.stderr()
