"""The shipped whole-socket model: what its card says it learned, and the physics its feed must obey."""

from __future__ import annotations

import numpy as np
import pytest
from checkout_cli import run_thrsim

from thrsim.config import SocketConfig
from thrsim.geometry.socket import generate_socket
from thrsim.learn.model_dir import SHIPPED_SOCKET_MODEL, load_model, reads_any_mesh
from thrsim.learn.simulator import ReamingSimulator

AXIS = np.array([0.0, 0.0, -1.0])


@pytest.fixture(scope="module")
def model():
    return load_model(SHIPPED_SOCKET_MODEL)


@pytest.fixture(scope="module")
def socket():
    return generate_socket(SocketConfig(element_size_mm=2.5))


def _ream(model, socket, force_n: float, frames: int = 24):
    simulator = ReamingSimulator(model=model, mesh=socket)
    results = [simulator.step(AXIS, force_n, reamer_mm=48.0) for _ in range(frames)]
    return results, float(sum(r.advance_m for r in results))


def test_the_card_records_what_the_model_learned(model):
    assert reads_any_mesh(model.settings) and model.settings.arch.reaction_head
    assert model.settings.arch.reaction_prior == "cutting"
    assert model.trained_reamer_mm == (44.0, 46.0, 48.0, 52.0, 54.0)  # 50 mm held out
    assert model.trained_force_n is not None and model.trained_inclination_deg == (0.0, 30.0)
    assert model.card["data"]["source"] == "datasets/socket-0.5.4" and len(model.card["data"]["reaction_cases"]) == 16


@pytest.mark.parametrize(("stage", "settings_file"), [("base", "socket-settings.json"), ("fine-tune", "socket-finetune-settings.json")])
def test_the_card_is_what_the_shipped_settings_files_train(model, stage, settings_file):
    """The documented two-stage recipe: 30 epochs from scratch, then a fine-tune from those weights;
    a card field newer than the training reads as its default, and the time budget did not stop it."""
    from thrsim.learn.settings import ModelSettings, preset_with_file

    expected = ModelSettings.model_validate(preset_with_file("socket", str(SHIPPED_SOCKET_MODEL.parent / settings_file))).model_dump()
    card_settings = model.card["settings"] if stage == "fine-tune" else model.card["training"]["init_from"]["settings"]
    recorded = ModelSettings.model_validate(card_settings).model_dump()
    for settings in (expected, recorded):
        settings["train"].pop("max_minutes")
    assert recorded == expected
    if stage == "fine-tune":  # the card's history is its last training's
        assert len(model.card["training"]["history"]) == model.card["training"]["epochs"] == expected["train"]["epochs"]


def test_no_push_no_cut_and_more_push_never_less(model, socket):
    still, depth = _ream(model, socket, 0.0)
    assert depth == 0.0 and not still[-1].removed.any()
    removed = []
    for force in (150.0, 230.0, 400.0):
        results, _ = _ream(model, socket, force)
        assert all(r.reaction_n is not None and 0.0 <= r.reaction_n <= force for r in results)  # the hold takes no more than the push
        removed.append(results[-1].removed_volume_m3)
    assert removed == sorted(removed) and removed[-1] > 0.0


def test_thrsim_ream_reams_the_whole_socket_with_the_shipped_model(tmp_path):
    done = run_thrsim(
        "ream",
        "--bone",
        "socket",
        "--reamers",
        "46,48",
        "--element-size",
        "2.5",
        "--frames",
        "30",
        "--out",
        str(tmp_path / "r"),
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "reamer 46 mm" in done.stdout and "reamer 48 mm" in done.stdout


def test_thrsim_ream_takes_the_next_reamer_once_the_last_is_seated(tmp_path):
    """The default sequence at the trainer's mesh: each reamer seats (its advance over the last half second
    falls under the rule's) before its frames run out, and none breaks through the bone."""
    import json

    from thrsim.learn.ream import SEATED_ADVANCE_MM

    done = run_thrsim("ream", "--bone", "socket", "--reamers", "46,48,50", "--out", str(tmp_path / "r"), "--json", timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads(done.stdout)
    steps = summary["reamers"]
    assert summary["seated_rule"]["advance_mm"] == SEATED_ADVANCE_MM
    assert [step["ended"] for step in steps] == ["seated"] * 3 and summary["end_reason"] == "completed"
    assert all(30 <= step["frames"] < 120 for step in steps)
    travel = [step["travel_mm"] for step in steps]
    assert travel == sorted(travel) and travel[-1] - travel[0] > SEATED_ADVANCE_MM
    assert [step["removed_volume_mm3"] for step in steps] == sorted(step["removed_volume_mm3"] for step in steps)
