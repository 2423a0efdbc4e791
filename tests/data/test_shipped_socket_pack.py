"""The 0.5 dataset ships as a learning pack: 51 socket windows at set feeds and 24 pushed, each with its own mesh and its reaction."""

from __future__ import annotations

from pathlib import Path

from thrsim.learn.cases import load_cases

PACK = Path(__file__).resolve().parents[2] / "datasets" / "socket-0.5.0"


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
