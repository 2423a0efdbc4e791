"""The 0.5 dataset ships as learning packs: 51 socket windows at set feeds and 24 pushed, each with
its own mesh and its reaction; beside them, the pushed whole sockets solved so far; the plan
solved again by solver 0.5.4, as far as it has gone; its long whole sockets and the prepared cavities
solved since, each packed apart."""

from __future__ import annotations

from pathlib import Path

from thrsim.config import LabelConfig, SocketSweepConfig
from thrsim.data.sweep import plan_socket_sweep
from thrsim.learn.cases import load_cases
from thrsim.learn.metrics import plate_left_mm3

PACK = Path(__file__).resolve().parents[2] / "datasets" / "socket-0.5.0"
WHOLE = PACK.parent / "socket-whole-0.5.1"
PACK_054 = PACK.parent / "socket-0.5.4"
LONG_054 = PACK.parent / "socket-long-0.5.4"
PREPARED_054 = PACK.parent / "socket-prepared-0.5.4"


def test_the_socket_pack_holds_the_plan_s_windows_with_what_the_socket_model_learns():
    _, cases = load_cases(PACK, one_mesh=False)
    fed = [case for case in cases if case.set_feed_mm_s is not None]
    pushed = [case for case in cases if case.set_feed_mm_s is None]
    splits = {split: sum(case.split == split for case in fed) for split in ("train", "validation", "test")}
    assert splits == {"train": 36, "validation": 6, "test": 9}
    assert sorted(case.split for case in pushed) == ["test"] * 4 + ["train"] * 20
    assert all(case.frames == 61 for case in fed) and all(case.frames <= 61 for case in pushed)
    assert sum(case.end_reason == "stalled" for case in pushed) == 2  # the pole windows at 0.2 N/mm²
    assert all(case.mesh is not None and case.reaction_n is not None for case in cases)
    assert all(case.alpha.shape[1] == case.mesh.n_tets for case in cases)  # each case on its own mesh, in either file
    assert all(case.motor_torque_n_m is not None and case.element_cutting_energy_j_m3 is not None for case in cases)
    assert {round(2e3 * case.teeth_radius_m) for case in cases} == {46, 48, 50, 52, 54}
    assert len({case.mesh.n_tets for case in cases}) > 5  # windows of the socket, not one mesh
    assert all(f.stat().st_size <= 15.5e6 for f in PACK.glob("part-*.h5"))


def test_the_whole_socket_pack_holds_the_plan_s_pushed_whole_sockets_meshed_whole():
    plan = {case.case_id: case for case in plan_socket_sweep(SocketSweepConfig()).cases}
    _, cases = load_cases(WHOLE, one_mesh=False)
    assert cases, "no whole socket packed"
    for case in cases:
        planned = plan[case.case_id]  # one of the plan's whole sockets, in its split
        assert case.case_id.startswith("whole_") and case.split == planned.split and case.set_feed_mm_s is None
        assert case.mesh is not None and case.mesh.n_tets > 100_000 and case.alpha.shape == (case.frames, case.mesh.n_tets)
        assert case.reaction_n is not None and case.motor_torque_n_m is not None and case.frames > 1
        assert {"cortical", "cancellous"} <= set(case.mesh.material_names)
    assert all(f.stat().st_size <= 15.5e6 for f in WHOLE.glob("part-*.h5"))


def test_the_0_5_4_pack_holds_the_plan_s_cases_of_this_solver_with_labels_that_keep_crushed_bone():
    import json

    import h5py

    plan = {case.case_id: case for case in plan_socket_sweep(SocketSweepConfig()).cases}
    _, cases = load_cases(PACK_054, one_mesh=False)
    assert all(case.case_id in plan and case.split == plan[case.case_id].split for case in cases)
    windows = [case for case in cases if not case.case_id.startswith("whole_")]
    whole = [case for case in cases if case.case_id.startswith("whole_")]
    assert len(windows) == sum(not case_id.startswith("whole_") for case_id in plan)  # every window of the plan
    native = {case_id for case_id in plan if case_id.endswith("_h1.5") and "_p" not in case_id}
    assert {case.case_id for case in whole} >= native  # the trainer's mesh, every native socket (a prepared cavity's: to come)
    assert all(case.reaction_n is not None and case.motor_torque_n_m is not None for case in cases)
    files = sorted(PACK_054.glob("part-*.h5"))
    assert files and all(f.stat().st_size <= 15.5e6 for f in files)
    assert sum(case.case_id.endswith("_h1") for case in whole) >= 7  # the 1.0 mm whole sockets solved so far
    assert sum("_r46_" in case.case_id and case.case_id.startswith("whole_s46_") for case in whole) >= 1  # one line to line
    for file in files:
        with h5py.File(file, "r") as f:
            assert json.loads(f.attrs["identity"])["thrsim_version"] == "0.5.4"
            assert json.loads(f.attrs["labels"]) == LabelConfig().model_dump()  # crushed cancellous bone stays bone
    # one split alone reads too, where a pack file holds none of its cases (evaluate --split test)
    _, test_cases = load_cases(PACK_054, splits=("test",), one_mesh=False)
    assert {case.case_id for case in test_cases} == {case.case_id for case in cases if case.split == "test"}


def test_the_long_pack_holds_the_plan_s_long_whole_sockets_held_seated_for_seconds():
    config = SocketSweepConfig()
    plan = {case.case_id: case for case in plan_socket_sweep(config).cases if case.frames == config.long_whole_socket_frames}
    _, cases = load_cases(LONG_054, one_mesh=False)
    assert {case.case_id for case in cases} == set(plan) and len(plan) == len(config.long_whole_sockets)
    for case in cases:
        # up to the plan's frames (a perforated case ends early), always past the 60 of every other case
        assert case.split == plan[case.case_id].split and config.frames < case.frames - 1 <= config.long_whole_socket_frames
        assert case.reaction_n is not None and case.motor_torque_n_m is not None and case.set_feed_mm_s is None
    assert {case.split for case in cases} == {"train", "test"}
    assert all(f.stat().st_size <= 15.5e6 for f in LONG_054.glob("part-*.h5"))


def test_the_prepared_pack_holds_the_plan_s_later_prepared_cavities_and_joins_the_0_5_4_pack(tmp_path):
    plan = {case.case_id: case for case in plan_socket_sweep(SocketSweepConfig()).cases}
    _, cases = load_cases(PREPARED_054, one_mesh=False)
    _, packed = load_cases(PACK_054, one_mesh=False)
    assert len(cases) == 9 and not {case.case_id for case in cases} & {case.case_id for case in packed}
    for case in cases:
        assert case.case_id.startswith("whole_") and "_p" in case.case_id and case.split == plan[case.case_id].split == "train"
        assert case.reaction_n is not None and case.motor_torque_n_m is not None and case.set_feed_mm_s is None
    # most breach the medial wall (their case ends there); three seat and run the plan's frames
    assert sum(case.end_reason == "medial_wall_breached" for case in cases) == 6
    # the one that holds: its seated reamer wears the plate ahead of the teeth (474 → 95 mm³ from frame 13 to 45)
    (holds,) = [case for case in cases if case.case_id == "whole_s48_p50_r52_g15t90_F230_h1.5"]
    mesh, alive = holds.mesh, holds.alpha >= LabelConfig().removed_threshold
    cortical = mesh.element_material == mesh.material_names.index("cortical")
    plate = [
        plate_left_mm3(mesh.centroids, abs(mesh.volumes), cortical, alive[k], holds.positions[k], holds.axis, holds.teeth_radius_m)
        for k in (13, 45)
    ]
    assert plate[0] > 300 and plate[1] < 0.3 * plate[0]
    assert all(f.stat().st_size <= 15.5e6 for f in PREPARED_054.glob("part-*.h5"))
    # the same dataset: its file beside the 0.5.4 pack's reads as one pack of both
    for file in sorted(PACK_054.glob("part-*.h5")):
        (tmp_path / file.name).symlink_to(file)
    (tmp_path / "part-005.h5").symlink_to(PREPARED_054 / "part-000.h5")
    _, joined = load_cases(tmp_path, one_mesh=False)
    assert {case.case_id for case in joined} == {case.case_id for case in cases + packed}
