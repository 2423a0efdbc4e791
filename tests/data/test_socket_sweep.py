"""The 0.5 dataset's plan: windows of the socket reamed one size up at set feeds, with held-out values."""

from __future__ import annotations

import json
import math
from collections import Counter

import pytest
from checkout_cli import run_thrsim

from thrsim.config import SocketSweepConfig, head_diameter_for_size, teeth_for_diameter
from thrsim.data.pack import read_pack
from thrsim.data.sweep import CaseSpec, plan_socket_sweep
from thrsim.learn.cases import load_cases
from thrsim.learn.graph import mesh_digest


def _settings(spec: CaseSpec) -> dict:
    return dict(spec.settings)


def test_the_plan_is_reproducible_balanced_and_holds_values_out():
    config = SocketSweepConfig()
    plan = plan_socket_sweep(config)
    again = plan_socket_sweep(config)
    assert [c.case_id for c in plan.cases] == [c.case_id for c in again.cases]
    assert len({c.case_id for c in plan.cases}) == len(plan.cases)
    long = [c for c in plan.cases if c.frames != config.frames]
    whole = [c for c in plan.cases if _settings(c)["socket.window_polar_deg"] is None and c not in long]
    pushed = [c for c in plan.cases if "feed_mm_s" not in _settings(c) and c not in whole and c not in long]
    fed = [c for c in plan.cases if "feed_mm_s" in _settings(c)]
    # each of the plan's whole sockets at each of its element sizes, the trainer's 1.5 mm first
    sizes = config.whole_socket_element_sizes_mm
    # native (one size up or line to line), then from a prepared cavity (a sequence's next step)
    entries = [(w[0], None, *w[1:]) for w in config.whole_sockets] + list(config.prepared_whole_sockets)
    assert config.prepared_whole_sockets and sizes[0] == 1.5 and len(whole) == len(sizes) * len(entries)
    assert [(c.inclination_deg, c.anteversion_deg, c.force_n, c.split) for c in whole] == [w[3:] for w in entries] * len(sizes)
    for case, (size, (socket_mm, prepared_mm, reamer_mm, *_)) in zip(whole, [(h, w) for h in sizes for w in entries], strict=True):
        built = case.case_config({"bone_kind": "socket"})
        assert built.feed_mm_s is None and built.socket.element_size_mm == size and case.case_id.endswith(f"_h{size:g}")
        assert built.socket.socket_diameter_mm == socket_mm and built.reamer.head_diameter_mm == head_diameter_for_size(reamer_mm)
        assert built.pre_ream_mm == prepared_mm and ("_p" in case.case_id) == (prepared_mm is not None)
    # the long whole sockets: a reamer held seated for seconds, at the trainer's mesh, named by their frames
    assert [(c.inclination_deg, c.anteversion_deg, c.force_n, c.split) for c in long] == [w[3:] for w in config.long_whole_sockets]
    assert {c.frames for c in long} == {config.long_whole_socket_frames} and config.long_whole_socket_frames > config.frames == plan.frames
    for case, (socket_mm, prepared_mm, reamer_mm, *_) in zip(long, config.long_whole_sockets, strict=True):
        built = case.case_config({"bone_kind": "socket"})
        assert built.frames == config.long_whole_socket_frames and built.socket.element_size_mm == sizes[0]
        assert case.case_id.endswith(f"_h{sizes[0]:g}_f{config.long_whole_socket_frames}") and built.pre_ream_mm == prepared_mm
        assert built.socket.socket_diameter_mm == socket_mm and built.reamer.head_diameter_mm == head_diameter_for_size(reamer_mm)
    splits = Counter(c.split for c in fed)
    assert splits == {"train": config.train_cases, "validation": config.validation_cases, "test": config.test_cases}
    # every pushed window at every pressure, along the socket's axis; the held-out windows only in test
    assert len(pushed) == len(config.pushed_windows) * len(config.push_pressures_n_mm2)
    held_windows = {tuple(w) for w in config.test_pushed_windows}
    for case in pushed:
        settings = _settings(case)
        window = (settings["socket.window_polar_deg"], settings["socket.window_azimuth_deg"])
        assert case.inclination_deg == 0.0 and (case.split == "test") == (window in held_windows)
        radius_mm = settings["socket.socket_diameter_mm"] / 2
        area_mm2 = 2 * math.pi * radius_mm**2 * (1 - math.cos(math.radians(config.window_half_angle_deg)))
        assert any(abs(case.force_n - p * area_mm2) <= 0.05 for p in config.push_pressures_n_mm2)
        assert case.case_config({"bone_kind": "socket"}).feed_mm_s is None
    train = [c for c in fed if c.split == "train"]
    held_sizes = {head_diameter_for_size(size) for size in config.test_reamer_sizes_mm}
    for case in train:
        settings = _settings(case)
        assert settings["reamer.head_diameter_mm"] not in held_sizes
        assert settings["feed_mm_s"] not in config.test_feeds_mm_s
        assert case.anteversion_deg not in config.test_anteversions_deg + config.validation_anteversions_deg
    # every train value of each axis comes about equally often
    polars = Counter(_settings(c)["socket.window_polar_deg"] for c in train)
    feeds = Counter(_settings(c)["feed_mm_s"] for c in train)
    assert set(polars) == set(config.window_polars_deg) and max(polars.values()) - min(polars.values()) <= 2
    assert set(feeds) == set(config.feeds_mm_s) and max(feeds.values()) - min(feeds.values()) <= 2
    # each test case reams with something never trained on; validation tilts toward its own direction
    for case in (c for c in fed if c.split == "test"):
        settings = _settings(case)
        assert (
            settings["reamer.head_diameter_mm"] in held_sizes
            or settings["feed_mm_s"] in config.test_feeds_mm_s
            or (case.inclination_deg > 0 and case.anteversion_deg in config.test_anteversions_deg)
        )
    for case in (c for c in fed if c.split == "validation"):
        assert case.inclination_deg > 0 and case.anteversion_deg in config.validation_anteversions_deg
    # every case is a valid socket case, and reads back from its manifest entry unchanged
    for case in plan.cases:
        built = case.case_config({"bone_kind": "socket"})
        assert built.reamer.tooth_count == teeth_for_diameter(built.reamer.head_diameter_mm)  # each size its own teeth
        assert built.bone_kind == "socket" and (built.feed_mm_s is None) == (case in pushed or case in whole or case in long)
        assert (built.socket.window_polar_deg is None) == (case in whole or case in long)
        assert CaseSpec(**json.loads(json.dumps(case.params()))) == case


def test_a_small_socket_dataset_runs_validates_and_resumes(tmp_path):
    plan = tmp_path / "plan.json"
    plan.write_text(
        json.dumps(
            {
                "train_cases": 1,
                "validation_cases": 0,
                "test_cases": 1,
                "feeds_mm_s": [20.0],
                "test_feeds_mm_s": [25.0],
                "inclinations_deg": [0.0, 15.0],
                "reamer_centres_mm": [[0.0, 0.0, 0.0]],
                "pushed_windows": [[0.0, 0.0, 44.0, 46.0]],
                "push_pressures_n_mm2": [0.8],
                "whole_sockets": [[44.0, 46.0, 0.0, 0.0, 230.0, "train"]],
                "prepared_whole_sockets": [],
                "long_whole_sockets": [[44.0, None, 46.0, 0.0, 0.0, 310.0, "train"]],
                "long_whole_socket_frames": 3,
                "whole_socket_element_sizes_mm": [3.0],
                "seed": 7,
            }
        )
    )
    coarse = tmp_path / "coarse.json"
    coarse.write_text(json.dumps({"socket": {"element_size_mm": 2.5}}))
    out = tmp_path / "data"
    args = (
        "dataset",
        "--bone",
        "socket",
        "--socket-plan",
        str(plan),
        "--config",
        str(coarse),
        "--frames",
        "2",
        "--out",
        str(out),
        "--json",
    )
    done = run_thrsim(*args, timeout=1200)
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(done.stdout)["generated"] == 5
    manifest = json.loads((out / "manifest.json").read_text())
    cases = manifest["cases"]
    long = cases.pop("whole_s44_r46_g0t0_F310_h3_f3")  # a long whole socket: more frames than the plan's other cases
    assert long["status"] == "complete" and long["frames"] == 4 and long["solver_summary"]["push_mean_n"] == pytest.approx(310.0)
    whole = cases.pop("whole_s44_r46_g0t0_F230_h3")  # the pushed whole socket, meshed whole at its own element size
    assert whole["status"] == "complete" and whole["split"] == "train" and whole["solver_summary"]["feed_mm_s"] is None
    assert whole["solver_summary"]["push_mean_n"] == pytest.approx(230.0)
    push = cases.pop("s44_n_r46_w0a0_push0.8")  # the pushed window: driven by 0.8 N/mm² over its area, no set feed
    assert push["status"] == "complete" and push["solver_summary"]["feed_mm_s"] is None
    assert push["params"]["force_n"] == pytest.approx(0.8 * 2 * math.pi * 22.0**2 * (1 - math.cos(math.radians(10.0))), abs=0.05)
    entries = list(cases.values())
    assert sorted(e["split"] for e in entries) == ["test", "train"] and all(e["status"] == "complete" for e in entries)
    assert manifest["split_rule"]["test_feeds_mm_s"] == [25.0]
    assert all(e["solver_summary"]["bone"] == "socket" and e["solver_summary"]["feed_mm_s"] in (20.0, 25.0) for e in entries)
    again = run_thrsim(*args, timeout=600)
    assert again.returncode == 0 and json.loads(again.stdout)["skipped"] == 5
    # the calibration reads the cases reamed along the socket's axis: more push, more seated feed
    info = run_thrsim("dataset", "info", str(out), "--json", timeout=600)
    assert info.returncode == 0, info.stderr[-2000:]
    calibration = json.loads(info.stdout)["socket_calibration"]
    along_axis = [
        e for e in entries if e["params"]["inclination_deg"] == 0.0 and not any(dict(e["params"]["settings"])["reamer_centre_mm"][:2])
    ]
    assert calibration["cases_used"] == len(along_axis) == 1  # seed 7: the train case reams the pole along the axis
    if along_axis:
        feeds = [calibration["seated"][push]["feed_mm_s"] for push in ("150", "230", "310")]
        assert all(math.isfinite(f) for f in feeds) and feeds[0] < feeds[1] < feeds[2]
    # and the pushed window, between the pressures that stalled and cut
    pushed = calibration["pushed"]
    assert pushed["cases_used"] == 1 and 0.8 in [round(v, 2) for v in pushed["windows"][0]["bracket_n_mm2"]]  # the push to 0.1 N
    # the pack keeps each window's own mesh beside its frames
    pack = tmp_path / "socket-pack.h5"
    packed = run_thrsim("dataset", "pack", str(out), "--out", str(pack), "--json", timeout=600)
    assert packed.returncode == 0, packed.stderr[-2000:]
    mesh, cases = read_pack(pack)
    assert len(cases) == 5 and all(case.mesh is not None for case in cases)  # its own, or its file's
    assert sorted(case.alpha.shape[0] for case in cases) == [3, 3, 3, 3, 4]  # each case its own frames
    assert len({mesh_digest(case.mesh) for case in cases}) >= 3  # windows of their own meshes, and the whole socket
    # the law's cases are told apart from windows in the pack too (a window keeps its held sides)
    _, learned = load_cases(pack, one_mesh=False)
    assert {case.case_id for case in learned if not case.is_window()} == {"whole_s44_r46_g0t0_F230_h3", "whole_s44_r46_g0t0_F310_h3_f3"}
    for case in cases:
        own = case.mesh
        assert case.alpha.shape[1] == own.n_tets and case.status.shape == case.alpha.shape
        assert set(own.material_names) == {"cortical", "cancellous"}


@pytest.mark.parametrize(
    ("plan", "says"),
    [
        ({"train_cases": 0}, "set-feed socket cases need train_cases"),
        (
            {
                "train_cases": 0,
                "validation_cases": 0,
                "test_cases": 0,
                "pushed_windows": [],
                "whole_sockets": [],
                "prepared_whole_sockets": [],
                "long_whole_sockets": [],
            },
            "no case",
        ),
        ({"whole_sockets": [[46, 48, 0, 0, 230, "holdout"]]}, "unknown split"),
        ({"prepared_whole_sockets": [[46, 48, 50, 0, 0, 230, "holdout"]]}, "unknown split"),
        ({"long_whole_sockets": [[46, None, 48, 0, 0, 230, "holdout"]]}, "unknown split"),
        ({"cancellous": ["spongy"]}, "unknown cancellous"),
        ({"windows": 3}, "windows"),
    ],
)
def test_a_bad_socket_plan_is_refused(tmp_path, plan, says):
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(plan))
    done = run_thrsim("dataset", "--bone", "socket", "--socket-plan", str(path), "--out", str(tmp_path / "data"))
    assert done.returncode == 2 and says in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "data").exists()


def test_the_cutting_threshold_lies_between_the_pressures_that_stalled_and_cut():
    from thrsim.data.calibration import cutting_threshold

    def window(polar, pressure, stalled):
        return {
            "window": [polar, 0.0],
            "socket_mm": 46.0,
            "pressure_n_mm2": pressure,
            "feed_mm_s": 0.0 if stalled else 1.0,
            "stalled": stalled,
        }

    found = cutting_threshold([window(0.0, 0.2, True), window(0.0, 0.35, False), window(0.0, 0.5, False), window(60.0, 0.2, False)])
    assert [b["bracket_n_mm2"] for b in found["bands"]] == [[0.2, 0.35], [0.0, 0.2]]
    assert [b["band_deg"] for b in found["bands"]] == [[0.0, 30.0], [30.0, 90.0]]
    # Σ p·A over the hemisphere of a 48 mm reamer: the pole band's cap (cos 0 − cos 30°) and the rest (cos 30°)
    low, high = found["seated_push_n"]["48"]
    cap, rest = 2 * math.pi * (1 - math.cos(math.radians(30))) * 24.0**2, 2 * math.pi * math.cos(math.radians(30)) * 24.0**2
    assert low == pytest.approx(0.2 * cap) and high == pytest.approx(0.35 * cap + 0.2 * rest)
