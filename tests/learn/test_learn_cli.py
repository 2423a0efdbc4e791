"""``thrsim train``, ``thrsim evaluate`` and ``thrsim ream`` run as a user runs them, on tiny data."""

from __future__ import annotations

import json
import shutil

import meshio
import numpy as np
import pytest
from learn_helpers import run_thrsim
from PIL import Image

from thrsim.learn.evaluation import windows
from thrsim.learn.model_dir import SHIPPED_MODEL


def test_train_writes_a_model_directory_and_refuses_to_overwrite_it(synthetic_dataset, settings_file, tmp_path):
    out = tmp_path / "model"
    result = run_thrsim("train", "--data", str(synthetic_dataset), "--out", str(out), "--settings", str(settings_file), "--json")
    assert result.returncode == 0, result.stderr
    card = json.loads(result.stdout)
    assert card["training"]["epochs"] == 1 and card["arch"] == "production"
    assert sorted(p.name for p in out.iterdir()) == ["advance.safetensors", "card.json", "mesh.safetensors", "network.safetensors"]
    again = run_thrsim("train", "--data", str(synthetic_dataset), "--out", str(out), "--settings", str(settings_file))
    assert again.returncode == 2
    assert again.stderr.count("\n") == 1 and "already holds a trained model" in again.stderr


def test_advance_only_refits_the_regressor_and_keeps_the_networks(tiny_model, synthetic_dataset, real_case, tmp_path):
    model = tmp_path / "model"
    shutil.copytree(tiny_model, model)
    (model / "advance.safetensors").unlink()
    networks = (model / "network.safetensors").read_bytes()
    result = run_thrsim("train", "--data", str(synthetic_dataset), "--out", str(model), "--advance-only", "--json")
    assert result.returncode == 0, result.stderr
    card = json.loads(result.stdout)
    assert card["advance"]["chosen"] in card["advance"]["models"] and "advance_refit_utc" in card
    assert (model / "network.safetensors").read_bytes() == networks
    assert json.loads((model / "card.json").read_text()) == card
    other = run_thrsim("train", "--data", str(real_case.parent), "--out", str(model), "--advance-only")
    assert other.returncode == 2 and other.stderr.count("\n") == 1
    # another kind by name: kept whatever its error, and the card's settings say so
    ridge = run_thrsim(
        "train", "--data", str(synthetic_dataset), "--out", str(model), "--advance-only", "--advance-kind", "ridge", "--json"
    )
    assert ridge.returncode == 0, ridge.stderr
    card = json.loads(ridge.stdout)
    assert card["advance"]["chosen"] == "ridge" and card["settings"]["train"]["advance_kind"] == "ridge"
    assert card["advance"]["chosen_by"] == "the training settings' advance_kind"
    unknown = run_thrsim("train", "--data", str(synthetic_dataset), "--out", str(model), "--advance-only", "--advance-kind", "tree")
    assert unknown.returncode == 2 and unknown.stderr.count("\n") == 1 and "--advance-kind" in unknown.stderr


def test_train_init_from_starts_from_a_trained_models_networks(tiny_model, synthetic_dataset, settings_file, tmp_path):
    from safetensors.numpy import load_file

    out = tmp_path / "tuned"
    result = run_thrsim(
        "train",
        "--data",
        str(synthetic_dataset),
        "--out",
        str(out),
        "--settings",
        str(settings_file),
        "--init-from",
        str(tiny_model),
        "--json",
    )
    assert result.returncode == 0, result.stderr
    init = json.loads(result.stdout)["training"]["init_from"]
    assert init["source"] == str(tiny_model) and len(init["weights_digest"]) == 64
    assert init["training"]["epochs"] == json.loads((tiny_model / "card.json").read_text())["training"]["epochs"]
    before, after = load_file(str(tiny_model / "network.safetensors")), load_file(str(out / "network.safetensors"))
    assert np.array_equal(before["gn.node_norm.mean"], after["gn.node_norm.mean"])  # normalisers kept, not refitted
    assert not all(np.array_equal(before[k], after[k]) for k in before)  # and the weights trained on
    wider = json.loads(settings_file.read_text())
    wider.setdefault("features", {}).update(front_hops=2, reach_margin_mm=2.0)  # the region grows, the inputs stay
    settings_file.write_text(json.dumps(wider))
    grown = run_thrsim(
        "train", "--data", str(synthetic_dataset), "--out", str(tmp_path / "grown"), "--settings", str(settings_file),
        "--init-from", str(tiny_model), "--json", "--overwrite",
    )  # fmt: skip
    assert grown.returncode == 0, grown.stderr
    assert json.loads(grown.stdout)["settings"]["features"]["front_hops"] == 2
    other = json.loads(settings_file.read_text())
    trained_corners = json.loads((tiny_model / "card.json").read_text())["settings"]["features"]["corners"]
    other["features"]["corners"] = not trained_corners  # another input
    settings_file.write_text(json.dumps(other))
    refused = run_thrsim(
        "train", "--data", str(synthetic_dataset), "--out", str(tmp_path / "other"), "--settings", str(settings_file),
        "--init-from", str(tiny_model),
    )  # fmt: skip
    assert refused.returncode == 2 and refused.stderr.count("\n") == 1 and "input features" in refused.stderr
    other["features"]["corners"] = not other["features"]["corners"]
    other["arch"]["message_passing_steps"] = 3
    settings_file.write_text(json.dumps(other))
    refused = run_thrsim(
        "train",
        "--data",
        str(synthetic_dataset),
        "--out",
        str(tmp_path / "other"),
        "--settings",
        str(settings_file),
        "--init-from",
        str(tiny_model),
    )
    assert refused.returncode == 2 and refused.stderr.count("\n") == 1 and "architecture" in refused.stderr
    assert not (tmp_path / "other").exists()


def test_train_refuses_a_folder_that_is_not_a_dataset(tmp_path):
    result = run_thrsim("train", "--data", str(tmp_path), "--out", str(tmp_path / "model"))
    assert result.returncode == 2 and "not a thrsim dataset" in result.stderr
    assert not (tmp_path / "model").exists()


def _check_scores(row: dict) -> None:
    for key in ("precision", "recall", "f1"):
        assert row[key] is None or 0.0 <= row[key] <= 1.0
    assert row["windows"] >= 1


def test_evaluate_json_is_keyed_by_inclination_then_horizon(tiny_model, synthetic_dataset):
    result = run_thrsim("evaluate", "--data", str(synthetic_dataset), "--model", str(tiny_model), "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    # the test split: θ 45 at γ 15 and 30; 12 frames, so t+1 and the rollout to the end
    for source in (report, report["mlp"], report["geometric"], report["tool_forced"]):
        assert {"15", "30"} <= set(source)
        for g in ("15", "30"):
            assert set(source[g]) == {"1", "end", "longest_horizon"}
            _check_scores(source[g]["1"])
            _check_scores(source[g]["end"])
    assert report["15"]["1"]["windows"] == 11  # t+1 from every frame with a next one
    assert report["15"]["end"]["windows"] == 1
    assert report["thesis_table_10_percent"]["0"]["60"]["f1"] == 92.9
    assert report["by_force"]["230"]["windows"] == 2  # one full window in each of the two test cases
    sparse = json.loads(
        run_thrsim("evaluate", "--data", str(synthetic_dataset), "--model", str(tiny_model), "--one-step-stride", "30", "--json").stdout
    )
    assert sparse["15"]["1"]["windows"] == 1 and sparse["15"]["end"] == report["15"]["end"]
    table = run_thrsim("evaluate", "--data", str(synthetic_dataset / "cases" / "g015.0_t045.0_f230N_h1mm.h5"), "--model", str(tiny_model))
    assert table.returncode == 0, table.stderr
    assert "thesis Table 10" in table.stdout and "geometric" in table.stdout


def test_evaluate_per_case_scores_each_case_from_its_first_frame_as_the_windows_do(tiny_model, synthetic_dataset):
    args = ("evaluate", "--data", str(synthetic_dataset), "--model", str(tiny_model), "--json")
    windows = json.loads(run_thrsim(*args).stdout)  # 12-frame cases: one window from frame 0 to the end each
    result = run_thrsim(*args, "--per-case")
    assert result.returncode == 0, result.stderr
    rows = json.loads(result.stdout)["cases"]
    assert len(rows) == 2 and {row["split"] for row in rows} == {"test"}
    for row in rows:
        gamma = "15" if "g015" in row["case_id"] else "30"
        for mode, source in (("autonomous", windows), ("tool_forced", windows["tool_forced"]), ("geometric", windows["geometric"])):
            assert row[mode]["f1"] == pytest.approx(source[gamma]["end"]["f1"]), (row["case_id"], mode)
        assert row["tool_forced"]["reamer_end_error_mm"] == 0.0 and row["geometric"]["reamer_end_error_mm"] == 0.0
        model_plate, solver_plate = row["tool_forced"]["plate_left_mm3"], row["tool_forced"]["solver_plate_left_mm3"]
        assert len(model_plate) == len(solver_plate) == row["frames"]  # frame 0 (the shared start) to the last
        assert model_plate[0] == solver_plate[0] and min(model_plate + solver_plate) >= 0
    table = run_thrsim("evaluate", "--data", str(synthetic_dataset), "--model", str(tiny_model), "--per-case")
    assert table.returncode == 0 and "reamer end mm" in table.stdout and "GN tool-forced" in table.stdout
    assert "plate left mm³ (solver)" in table.stdout and "sphere depth mm" in table.stdout


def test_evaluate_refuses_a_model_of_another_mesh(tiny_model, real_case):
    result = run_thrsim("evaluate", "--data", str(real_case), "--model", str(tiny_model), "--json")
    assert result.returncode == 2 and "another mesh" in result.stderr and result.stdout == ""


def test_evaluate_refuses_cases_without_damage_for_a_model_that_reads_it(tiny_model, synthetic_dataset, tmp_path):
    import h5py

    case = tmp_path / "old.h5"
    shutil.copy(synthetic_dataset / "cases" / "g015.0_t045.0_f230N_h1mm.h5", case)
    with h5py.File(case, "r+") as f:  # as solver 0.3.0 wrote it
        del f["frames/damage"], f["frames/damage_initiation"]
    result = run_thrsim("evaluate", "--data", str(case), "--model", str(tiny_model), "--json")
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and "do not record damage" in result.stderr


def test_windows_cover_every_horizon_or_the_end():
    assert windows(12, 30, one_step_stride=30) == [(0, ["1", "end"], 11)]
    full = [(0, ["1", "30", "60"], 60), (30, ["1", "30", "60"], 60), (60, ["1", "30", "60"], 60), (90, ["1", "30", "end"], 30)]
    assert windows(121, 30, one_step_stride=30) == full


def test_one_step_windows_fill_every_frame_between_the_full_ones():
    every = windows(121, 30)
    assert [w for w in every if w[1] != ["1"]] == windows(121, 30, one_step_stride=30)
    assert sorted(start for start, _, _ in every) == list(range(120))  # t+1 from every frame that has a next one
    assert all(length == 1 for start, keys, length in every if keys == ["1"])
    assert [start for start, keys, _ in windows(121, 30, one_step_stride=7) if keys == ["1"]] == [
        s for s in range(120) if s % 7 == 0 and s % 30
    ]


def test_ream_writes_a_paraview_series_and_a_summary(tiny_model, tmp_path):
    out = tmp_path / "ream"
    png = tmp_path / "last.png"
    result = run_thrsim(
        "ream",
        "--inclination",
        "15",
        "--anteversion",
        "30",
        "--frames",
        "3",
        "--model",
        str(tiny_model),
        "--out",
        str(out),
        "--png",
        str(png),
        "--json",
    )
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["png"] == str(png)
    picture = np.asarray(Image.open(png).convert("RGB"))
    assert picture.shape == (768, 1024, 3) and len(np.unique(picture.reshape(-1, 3), axis=0)) > 20  # the bone is drawn
    assert summary["frames"] == 3 and len(summary["removed_per_frame"]) == 3
    assert summary["png_frame"] <= 3 and summary["png_bone_left"] >= 0.1 * summary["elements"]
    assert summary["end_reason_text"].startswith(summary["end_reason"].replace("_", " "))
    assert summary["removed_all"] is (summary["removed"] == summary["elements"])
    assert summary["series_path"] == str(out.resolve() / "ream.pvd") and summary["series_path"] in summary["open_with"]
    assert "ParaView" in summary["open_with"]
    assert (summary["cup_inclination_deg"], summary["cup_anteversion_deg"]) == pytest.approx((54.906, 11.208), abs=1e-3)
    assert json.loads((out / "ream.json").read_text()) == summary
    pvd = (out / "ream.pvd").read_text()
    assert pvd.count("<DataSet") == 8 and 'part="1"' in pvd
    bone = meshio.read(out / "bone_0003.vtu")
    assert "alpha" in bone.cell_data and "removed" in bone.cell_data
    assert len(bone.cell_data["alpha"][0]) == summary["elements"]
    assert int(np.sum(bone.cell_data["removed"][0])) == summary["removed"]
    reamer = meshio.read(out / "reamer_0003.vtu")
    centre = np.array(summary["reamer_end_mm"])
    assert np.allclose(np.linalg.norm(reamer.points - centre, axis=1), 22.9, atol=1e-6)


def test_ream_says_why_it_stopped_what_it_removed_and_how_to_open_the_series(tiny_model, tmp_path):
    out = tmp_path / "ream"
    result = run_thrsim("ream", "--frames", "2", "--model", str(tiny_model), "--out", str(out))
    assert result.returncode == 0, result.stderr
    summary = json.loads((out / "ream.json").read_text())
    text = result.stdout
    assert f"stopped: {summary['end_reason_text']}" in text
    assert f"frames: {summary['frames']} run of 2 asked" in text
    assert f"removed: {summary['removed']} of {summary['elements']} elements" in text
    assert "ParaView" in text and str(out.resolve() / "ream.pvd") in text
    assert "cup 54.9°/11.2° radiographic" in text


def test_ream_takes_clinical_cup_angles(tiny_model, tmp_path):
    from thrsim.nav.bone_frame import bone_angles_from_cup

    args = ["--cup-inclination", "45", "--cup-anteversion", "20", "--frames", "1", "--model", str(tiny_model), "--json"]
    result = run_thrsim("ream", *args, "--out", str(tmp_path / "ream"))
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert (summary["inclination_deg"], summary["anteversion_deg"]) == pytest.approx(bone_angles_from_cup(45.0, 20.0))
    assert (summary["cup_inclination_deg"], summary["cup_anteversion_deg"]) == pytest.approx((45.0, 20.0))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--force", "-5"], "non-negative"),
        (["--side", "middle"], "--side: must be right or left"),
        (["--inclination", "95"], "--inclination"),
        (["--frames", "0"], "--frames"),
        (["--png", "last.jpg"], "--png"),
    ],
)
def test_ream_refuses_bad_input_and_writes_nothing(tiny_model, tmp_path, args, message):
    out = tmp_path / "ream"
    base = {"--inclination": "15", "--anteversion": "30", "--frames": "2"}
    for flag, value in zip(args[::2], args[1::2], strict=True):
        base[flag] = value
    flat = [x for kv in base.items() for x in kv]
    result = run_thrsim("ream", *flat, "--model", str(tiny_model), "--out", str(out))
    assert result.returncode == 2, result.stderr
    assert message in result.stderr and result.stderr.count("\n") == 1
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_ream_defaults_to_the_default_case_and_creates_its_folder(tiny_model, tmp_path):
    out = tmp_path / "runs" / "first" / "ream"
    result = run_thrsim("ream", "--frames", "2", "--model", str(tiny_model), "--out", str(out), "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert (summary["inclination_deg"], summary["anteversion_deg"], summary["force_n"]) == (15.0, 30.0, 230.0)
    assert (out / "ream.json").is_file()
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    result = run_thrsim("ream", "--frames", "1", "--model", str(tiny_model), "--out", str(blocked / "ream"))
    assert result.returncode == 2 and "is not a folder" in result.stderr


def test_ream_refuses_a_folder_that_is_not_a_model(tmp_path):
    result = run_thrsim("ream", "--inclination", "15", "--anteversion", "30", "--model", str(tmp_path), "--out", str(tmp_path / "ream"))
    assert result.returncode == 2 and "not a thrsim model directory" in result.stderr
    assert not (tmp_path / "ream").exists()


def test_the_shipped_model_reams_a_tilted_case_through_and_stops_there(tmp_path):
    # the held-out γ 45°, θ 45° case: the solver's reamer swept through the whole patch in 12 frames
    out, png = tmp_path / "ream", tmp_path / "ream.png"
    args = ["--inclination", "45", "--anteversion", "45", "--frames", "60", "--png", str(png)]
    result = run_thrsim("ream", *args, "--out", str(out), "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["model"]["path"] == str(SHIPPED_MODEL)
    assert summary["end_reason"] == "passed_through" and summary["frames_requested"] == 60
    assert 6 <= summary["frames"] <= 24 and len(summary["removed_per_frame"]) == summary["frames"]
    assert summary["removed"] >= 0.9 * summary["elements"]
    assert (out / "ream.pvd").read_text().count("<DataSet") == 2 * (summary["frames"] + 1)
    # the last frames hold little or no bone: the picture is of the last that still shows it
    assert summary["removed_all"] and summary["png_frame"] < summary["frames"]
    assert summary["png_bone_left"] >= 0.1 * summary["elements"]
    picture = np.asarray(Image.open(png).convert("RGB")).astype(int)
    coloured = picture.max(axis=2) - picture.min(axis=2) > 40  # bone is drawn in colour on a grey background
    assert coloured.mean() > 0.1 and picture.std() > 30  # the last frame, with no bone, drew 0 and 9


@pytest.mark.parametrize("option", ["--start-stride", "--one-step-stride"])
def test_evaluate_refuses_a_stride_below_one(tiny_model, synthetic_dataset, option):
    result = run_thrsim("evaluate", "--data", str(synthetic_dataset), "--model", str(tiny_model), option, "0")
    assert result.returncode == 2 and result.stderr.count("\n") == 1 and option in result.stderr
