"""Sweeps: local pool, Dask, manifest, resume, adoption, crash recovery, refusals."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import socket

import numpy as np
import pytest

from thrsim.data.case_file import data_digest, file_sha256, validate_case
from thrsim.data.generate import load_dataset, read_manifest, resolve_solver, run_sweep
from thrsim.data.sweep import plan_sweep
from thrsim.data.synthetic import synthetic_run_case
from thrsim.errors import ThrsimInputError

pytestmark = pytest.mark.timeout(120)


def small_plan(frames=3, anteversions=(0.0, 90.0)):
    return plan_sweep((0.0, 30.0), anteversions, frames=frames, extra_forces_n=())


def crash_once(case, out, progress=None):
    """Kill the worker process (SIGKILL) the first time, for the case at θ = 90; then behave."""
    marker = os.environ["THRSIM_TEST_CRASH_MARKER"]
    if case.anteversion_deg == 90.0 and not os.path.exists(marker):
        open(marker, "w").close()
        os.kill(os.getpid(), signal.SIGKILL)
    return synthetic_run_case(case, out, progress)


def always_fails(case, out, progress=None):
    if case.inclination_deg > 0:
        raise RuntimeError("solver blew up at frame 2")
    return synthetic_run_case(case, out, progress)


def test_local_sweep_manifest_and_resume(tmp_path):
    root = tmp_path / "ds"
    plan = small_plan()
    events = []
    result = run_sweep(root, plan, solver="synthetic", workers=2, on_event=events.append)
    assert (result.total, result.complete, result.skipped, result.failed) == (3, 3, 0, {})
    assert result.notes and "one physical case" in result.notes[0]
    manifest = read_manifest(root)
    assert manifest["format"] == "thrsim-dataset"
    assert len(manifest["cases"]) == 3
    for entry in manifest["cases"].values():
        path = root / entry["file"]
        assert entry["status"] == "complete" and entry["frames"] == 3
        assert entry["sha256"] == file_sha256(path) and entry["data_digest"] == data_digest(path)
        assert entry["solver"] == "synthetic" and entry["solver_version"] and entry["config_hash"]
        assert entry["wall_s"] > 0 and entry["split"] in ("train", "validation", "test")
        assert validate_case(path)["frames"] == 3
    assert manifest["cases"]["g030.0_t090.0_f230N"]["split"] == "validation"
    assert manifest["cases"]["g000.0_t000.0_f230N"]["params"]["aliases"] == [0.0, 90.0]
    assert sorted(p.name for p in (root / "cases").iterdir()) == sorted(f"{c}.h5" for c in manifest["cases"])
    mtimes = {p.name: p.stat().st_mtime_ns for p in (root / "cases").iterdir()}

    # rerun: everything skipped, nothing rewritten
    again = run_sweep(root, plan, solver="synthetic", workers=1)
    assert (again.complete, again.skipped) == (0, 3)
    assert {p.name: p.stat().st_mtime_ns for p in (root / "cases").iterdir()} == mtimes

    # an incomplete leftover and a damaged file are redone; an orphan complete file is adopted
    (root / "cases" / "g030.0_t000.0_f230N.h5.deadbeef.part").write_bytes(b"half")
    damaged = root / "cases" / "g030.0_t090.0_f230N.h5"
    damaged.write_bytes(damaged.read_bytes()[:1000])
    manifest = read_manifest(root)
    del manifest["cases"]["g030.0_t000.0_f230N"]  # as if killed between rename and manifest write
    (root / "manifest.json").write_text(json.dumps(manifest))
    third = run_sweep(root, plan, solver="synthetic", workers=1)
    assert (third.complete, third.skipped, third.adopted) == (1, 1, 1)
    assert not list((root / "cases").glob("*.part"))
    assert all(e["status"] == "complete" for e in read_manifest(root)["cases"].values())
    validate_case(damaged)

    # a file of the same orientation solved with another configuration is redone, never adopted
    elsewhere = tmp_path / "elsewhere"
    run_sweep(elsewhere, small_plan(), solver="synthetic", workers=1, template_overrides={"frame_rate_hz": 30.0})
    stranger = elsewhere / "cases" / "g030.0_t000.0_f230N.h5"
    (root / "cases" / stranger.name).write_bytes(stranger.read_bytes())
    manifest = read_manifest(root)
    del manifest["cases"]["g030.0_t000.0_f230N"]
    (root / "manifest.json").write_text(json.dumps(manifest))
    fourth = run_sweep(root, plan, solver="synthetic", workers=1)
    assert (fourth.complete, fourth.skipped, fourth.adopted) == (1, 2, 0)
    assert file_sha256(root / "cases" / stranger.name) != file_sha256(stranger)

    # a plan that now solves a case otherwise (same name, another setting) redoes it; the others are kept
    changed = dataclasses.replace(plan, cases=[dataclasses.replace(plan.cases[0], settings=(("contact.friction", 0.25),)), *plan.cases[1:]])
    fifth = run_sweep(root, changed, solver="synthetic", workers=1)
    assert (fifth.complete, fifth.skipped, fifth.adopted) == (1, 2, 0)
    sixth = run_sweep(root, plan, solver="synthetic", workers=1)
    assert (sixth.complete, sixth.skipped) == (1, 2)

    # growth with the same configuration: only the new case runs
    grown = run_sweep(root, small_plan(anteversions=(0.0, 90.0, 135.0)), solver="synthetic", workers=1)
    assert (grown.complete, grown.skipped) == (1, 3)
    assert [e["case_id"] for e in load_dataset(root, split="test")] == ["g030.0_t135.0_f230N"]


def test_refusals_touch_nothing(tmp_path):
    root = tmp_path / "ds"
    run_sweep(root, small_plan(), solver="synthetic", workers=1)
    before = {p: p.stat().st_mtime_ns for p in root.rglob("*")}
    with pytest.raises(ThrsimInputError, match="different configuration.*frames"):
        run_sweep(root, small_plan(frames=4), solver="synthetic", workers=1)
    with pytest.raises(ThrsimInputError, match="different configuration.*solver"):
        run_sweep(root, small_plan(), solver="thrsim.data.synthetic:block_mesh", workers=1)
    with pytest.raises(ThrsimInputError, match="different configuration"):
        run_sweep(root, small_plan(), solver="synthetic", workers=1, template_overrides={"frame_rate_hz": 30.0})
    assert {p: p.stat().st_mtime_ns for p in root.rglob("*")} == before

    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(ThrsimInputError, match="not a thrsim dataset"):
        run_sweep(other, small_plan(), solver="synthetic")
    with pytest.raises(ThrsimInputError, match="unknown solver|not available"):
        run_sweep(tmp_path / "new", small_plan(), solver="nope")
    assert not (tmp_path / "new").exists()


@pytest.mark.timeout(25)  # Dask's own connect timeout is 30 s: a sweep that ignored ours would hang past this
def test_unreachable_scheduler_fails_fast(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(ThrsimInputError, match=r"cannot reach the Dask scheduler at tcp://127\.0\.0\.1:\d+ within 1 s"):
        run_sweep(tmp_path / "ds", small_plan(), solver="synthetic", scheduler=f"tcp://127.0.0.1:{port}", connect_timeout_s=1.0)
    assert not (tmp_path / "ds").exists()
    with pytest.raises(ThrsimInputError, match="tcp://HOST:PORT"):
        run_sweep(tmp_path / "ds", small_plan(), solver="synthetic", scheduler="tcp://nohostport")


def test_worker_killed_mid_case_is_retried(tmp_path, monkeypatch):
    monkeypatch.setenv("THRSIM_TEST_CRASH_MARKER", str(tmp_path / "crashed"))
    events = []
    result = run_sweep(tmp_path / "ds", small_plan(), solver=crash_once, workers=2, on_event=events.append)
    assert (tmp_path / "crashed").exists()
    assert any(e.status == "retry" for e in events)
    assert result.complete == 3 and not result.failed
    for entry in load_dataset(tmp_path / "ds"):
        validate_case(entry["path"])
    assert read_manifest(tmp_path / "ds")["cases"]["g030.0_t090.0_f230N"]["attempts"] >= 2


def test_solver_failure_recorded_and_retried_on_rerun(tmp_path):
    root = tmp_path / "ds"
    result = run_sweep(root, small_plan(), solver=always_fails, workers=1)
    assert result.complete == 1 and len(result.failed) == 2
    assert "blew up" in next(iter(result.failed.values()))
    manifest = read_manifest(root)
    assert sorted(e["status"] for e in manifest["cases"].values()) == ["complete", "failed", "failed"]
    assert not list((root / "cases").glob("*.part")) and not list((root / "cases").glob(".*"))
    assert len(load_dataset(root)) == 1


def test_dask_cluster_matches_local(tmp_path):
    distributed = pytest.importorskip("distributed")
    plan = small_plan()
    local = run_sweep(tmp_path / "local", plan, solver="synthetic", workers=2)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None) as cluster:
        remote = run_sweep(tmp_path / "dask", plan, solver="synthetic", scheduler=cluster.scheduler_address)
    assert remote.complete == local.complete == 3
    assert "Dask scheduler" in remote.executor
    a, b = read_manifest(tmp_path / "local")["cases"], read_manifest(tmp_path / "dask")["cases"]
    assert a.keys() == b.keys()
    for case_id in a:
        assert a[case_id]["data_digest"] == b[case_id]["data_digest"]
        fa, fb = tmp_path / "local" / a[case_id]["file"], tmp_path / "dask" / b[case_id]["file"]
        import h5py

        with h5py.File(fa) as x, h5py.File(fb) as y:
            for name in (
                "mesh/nodes",
                "mesh/tets",
                "frames/status",
                "frames/peeq",
                "frames/von_mises",
                "frames/reamer_position",
                "frames/energy",
            ):
                np.testing.assert_array_equal(x[name][()], y[name][()])


def test_real_solver_sweep_local_matches_dask(tmp_path):
    """The explicit FEM solver on a coarse bone, 2 frames: local pool and Dask give identical datasets.

    Bit-identical results need the same numerical threads per case (numba's parallel reductions
    depend on the thread count): 2 local workers on 2 cores and Dask tasks both use 1 thread.
    """
    distributed = pytest.importorskip("distributed")
    pytest.importorskip("thrsim.physics.reaming_case")
    plan = plan_sweep((30.0,), (0.0, 90.0), frames=2, extra_forces_n=(), element_sizes_mm=(1.2,))
    local = run_sweep(tmp_path / "local", plan, solver="fem", workers=2, threads=1)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None) as cluster:
        remote = run_sweep(tmp_path / "dask", plan, solver="fem", scheduler=cluster.scheduler_address, threads=1)
    assert local.complete == remote.complete == 2 and not local.failed and not remote.failed
    a, b = read_manifest(tmp_path / "local")["cases"], read_manifest(tmp_path / "dask")["cases"]
    for case_id, entry in a.items():
        summary = validate_case(tmp_path / "local" / entry["file"])
        assert summary["frames"] == 3 and summary["elements"] > 0  # frame 0 + 2 frames
        assert entry["removed"] == b[case_id]["removed"]
        assert entry["data_digest"] == b[case_id]["data_digest"]
        assert entry["solver_summary"]["end_reason"]


def test_solvers_by_name_are_thrsims_own_only(tmp_path, monkeypatch):
    marker = tmp_path / "imported"
    (tmp_path / "outside_solver.py").write_text(f"open({str(marker)!r}, 'w').close()\ndef run(case, out):\n    return {{}}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("outside_solver:run", "os:system", "subprocess:run"):
        with pytest.raises(ThrsimInputError, match="only thrsim's own solvers"):
            resolve_solver(name)
        with pytest.raises(ThrsimInputError, match="only thrsim's own solvers"):
            run_sweep(tmp_path / "ds", small_plan(), solver=name)
    assert not marker.exists() and not (tmp_path / "ds").exists()
    assert resolve_solver("synthetic") is synthetic_run_case
    assert resolve_solver(crash_once) is crash_once  # Python callers may pass their own callable


def test_solver_rates_group_complete_cases_by_inclination_and_force():
    from thrsim.data.info import solver_rates

    def case(gamma, force, feed, end="perforated", status="complete", wall_s=1800.0):
        summary = {"end_reason": end, "frames": 90, "feed_rate_mm_s": feed, "removal_rate_mm3_s": 200 * feed if feed is not None else None}
        return {"status": status, "params": {"inclination_deg": gamma, "force_n": force}, "solver_summary": summary, "wall_s": wall_s}

    entries = {
        "a": case(15, 230, 1.0),
        "b": case(15, 230, 3.0),
        "c": case(15, 230, 1.4, end="completed"),
        "d": case(0, 150, None, end="completed"),
        "e": case(45, 230, 9.0, status="pending"),
        "f": case(0, 230, 0.9),
    }
    rates = solver_rates(entries)
    assert list(rates) == ["0/150", "0/230", "15/230"]  # by γ, then force; pending cases left out
    assert rates["15/230"]["cases"] == 3 and rates["15/230"]["end_reasons"] == {"perforated": 2, "completed": 1}
    assert rates["15/230"]["feed_rate_mm_s"] == 1.4 and rates["15/230"]["removal_rate_mm3_s"] == 280.0  # medians
    assert rates["15/230"]["worker_hours"] == 1.5
    assert rates["0/150"]["feed_rate_mm_s"] is None and rates["0/150"]["excursion_median_mm"] is None


def test_a_new_dataset_adopts_the_plans_cases_solved_elsewhere_and_refuses_strangers(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    run_sweep(elsewhere, small_plan(), solver="synthetic", workers=1)
    solved = elsewhere / "cases" / "g030.0_t000.0_f230N.h5"
    root = tmp_path / "ds"
    (root / "cases").mkdir(parents=True)
    (root / "cases" / "mine.h5").write_bytes(solved.read_bytes())
    with pytest.raises(ThrsimInputError, match="not the plan's cases"):
        run_sweep(root, small_plan(), solver="synthetic", workers=1)
    (root / "cases" / "mine.h5").rename(root / "cases" / solved.name)
    result = run_sweep(root, small_plan(), solver="synthetic", workers=1)
    assert (result.adopted, result.complete) == (1, 2)
    assert file_sha256(root / "cases" / solved.name) == file_sha256(solved)
    adopted = read_manifest(root)["cases"][solved.stem]
    assert adopted["wall_s"] is None and adopted["solver_summary"]["end_reason"] == validate_case(solved)["end_reason"]
    # an adopted case was not timed here: it packs all the same
    from thrsim.data.pack import read_pack, write_pack

    write_pack(root, tmp_path / "pack.h5")
    assert {case.case_id for case in read_pack(tmp_path / "pack.h5")[1]} >= {solved.stem}


def test_a_worker_capped_after_numba_started_its_threads_still_compiles():
    """thrsim starts Numba's threads on import; a worker capped afterwards (a spawned pool's
    initializer, a Dask task) must still compile kernels, with its cap in force."""
    import subprocess
    import sys

    code = (
        "import numba, thrsim.physics.explicit\n"
        "from thrsim.data.executor import cap_numerical_threads\n"
        "cap_numerical_threads(1)\n"
        "assert numba.njit(lambda x: x + 1)(1) == 2\n"  # a compilation re-reads Numba's environment
        "print(numba.get_num_threads())\n"
    )
    env = {**os.environ, "NUMBA_NUM_THREADS": "2"}
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-500:]
    assert run.stdout.split() == ["1"]


def test_a_local_pool_states_the_threads_each_case_gets(tmp_path):
    """Asked for one thread a case, the pool says so (it said cores ÷ workers) and its workers use one."""
    result = run_sweep(tmp_path / "ds", small_plan(), solver="synthetic", workers=1, threads=1)
    assert result.executor == "local process pool, 1 worker(s) × 1 thread(s)"
    assert read_manifest(tmp_path / "ds")["runs"][-1]["threads_per_case"] == 1
