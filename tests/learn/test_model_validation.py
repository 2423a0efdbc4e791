"""A corrupt or tampered model folder is refused before use: one line on stderr, exit 2, nothing
written; never a traceback, an endless loop or a crash (issue 27, item 5).

Each case copies the shipped model and spoils one part of it: a safetensors file, a card field,
an array the card implies, a regressor tree.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from checkout_cli import run_main
from learn_helpers import use_forest_regressor
from safetensors import safe_open
from safetensors.numpy import load_file, save_file
from safetensors.torch import load_file as load_tensors
from safetensors.torch import save_file as save_tensors

from thrsim.learn.model_dir import ADVANCE, CARD, MESH, NETWORK, SHIPPED_MODEL

pytestmark = pytest.mark.timeout(120)


def _truncate(name: str, keep: float):
    def spoil(folder: Path) -> None:
        data = (folder / name).read_bytes()
        (folder / name).write_bytes(data[: int(len(data) * keep)])

    return spoil


def _card(change):
    def spoil(folder: Path) -> None:
        card = json.loads((folder / CARD).read_text())
        change(card)
        (folder / CARD).write_text(json.dumps(card))

    return spoil


def _advance(change, kind: str = "random_forest"):
    def spoil(folder: Path) -> None:
        if kind == "random_forest":
            use_forest_regressor(folder)
        arrays = load_file(str(folder / ADVANCE))
        assert safe_open(str(folder / ADVANCE), "np").metadata()["kind"] == kind
        change(arrays)
        save_file(arrays, str(folder / ADVANCE), metadata={"kind": kind})

    return spoil


def _network(change):
    def spoil(folder: Path) -> None:
        tensors = load_tensors(str(folder / NETWORK))
        change(tensors)
        save_tensors(tensors, str(folder / NETWORK))

    return spoil


def _cycle(arrays: dict) -> None:
    root = int(arrays["roots"][0])
    arrays["left"][root] = arrays["right"][root] = root


def _first_tensor(tensors: dict, value: float) -> None:
    name = sorted(tensors)[0]
    tensors[name] = torch.full_like(tensors[name], value)


SPOILED = {
    "truncated_network": (_truncate(NETWORK, 0.5), "unreadable model file"),
    "truncated_mesh": (_truncate(MESH, 0.01), "unreadable model file"),
    "garbage_advance": (lambda folder: (folder / ADVANCE).write_bytes(b"\x10" + b"\x00" * 7 + b"garbage"), "unreadable model file"),
    "empty_advance": (_truncate(ADVANCE, 0.0), "unreadable model file"),
    "card_deep_json": (lambda folder: (folder / CARD).write_text("[" * 100_000 + "]" * 100_000), "unreadable model card"),
    "card_radius_text": (_card(lambda c: c["reamer"].update(teeth_radius_m="abc")), "reamer.teeth_radius_m"),
    "card_radius_negative": (_card(lambda c: c["reamer"].update(teeth_radius_m=-0.02)), "reamer.teeth_radius_m"),
    "card_no_labels": (_card(lambda c: c.pop("labels")), "labels"),
    "card_no_data": (_card(lambda c: c.pop("data")), "data"),
    "card_threshold_nan": (_card(lambda c: c["labels"].update(removed_threshold=float("nan"))), "removed_threshold"),
    "card_elements_wrong": (_card(lambda c: c["mesh"].update(elements=c["mesh"]["elements"] + 1)), "the card says"),
    "card_settings_list": (_card(lambda c: c.update(settings=[1])), "settings"),
    "forest_cycle": (_advance(_cycle), "a cycle or out of range"),
    "forest_index_2_30": (_advance(lambda a: a["left"].__setitem__(0, 2**30)), "1073741824"),
    "forest_root_out_of_range": (_advance(lambda a: a["roots"].__setitem__(0, 2**40)), "roots"),
    "forest_feature_out_of_range": (_advance(lambda a: a["feature"].__setitem__(0, 10**6)), "feature 1000000"),
    "forest_value_nan": (_advance(lambda a: a["value"].__setitem__(3, np.nan)), "'value'"),
    "forest_without_values": (_advance(lambda a: a.pop("value")), "lacks array(s) value"),
    "svr_dual_coef_nan": (_advance(lambda a: a["dual_coef"].__setitem__(0, np.nan), "svr"), "'dual_coef'"),
    "svr_support_vectors_short": (_advance(lambda a: a.update(support_vectors=a["support_vectors"][:-1]), "svr"), "support_vectors"),
    "svr_without_gamma": (_advance(lambda a: a.pop("gamma"), "svr"), "lacks array(s) gamma"),
    "weights_nan": (_network(lambda t: _first_tensor(t, float("nan"))), "NaN or infinite"),
    "weights_half_precision": (_network(lambda t: t.update({k: v.half() for k, v in t.items() if v.is_floating_point()})), "float16"),
    "weights_missing_one": (_network(lambda t: t.pop(sorted(t)[-1])), "missing"),
}


@pytest.mark.parametrize("case", sorted(SPOILED))
def test_a_spoiled_model_folder_is_one_line_and_exit_2(case, tmp_path, monkeypatch, capsys):
    spoil, needle = SPOILED[case]
    model = tmp_path / "model"
    shutil.copytree(SHIPPED_MODEL, model)
    spoil(model)
    code, out, err = run_main(monkeypatch, capsys, "ream", "--model", str(model), "--frames", "2", "--out", str(tmp_path / "out"), "--json")
    assert code == 2, (code, out, err)
    assert "Traceback" not in err and out == ""
    assert len(err.splitlines()) == 1 and err.startswith("thrsim: error: "), err
    assert needle in err, err
    assert not (tmp_path / "out").exists()


def test_the_shipped_model_passes_its_checks(tmp_path, monkeypatch, capsys):
    code, out, err = run_main(monkeypatch, capsys, "ream", "--frames", "2", "--out", str(tmp_path / "out"), "--json")
    assert code == 0, err
    assert json.loads(out)["frames"] == 2
