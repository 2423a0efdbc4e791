"""`thrsim dataset --out DIR ...` and `thrsim dataset info DIR`, in process and as a killed subprocess."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import h5py
import pytest
from checkout_cli import THRSIM, checkout_env, run_main

from thrsim.data.case_file import validate_case
from thrsim.data.generate import read_manifest

pytestmark = pytest.mark.timeout(120)

SMALL = ["--inclinations", "0,30", "--anteversions", "0:90:90", "--frames", "3", "--extra-forces", "none", "--solver", "synthetic"]


def test_dataset_then_info(tmp_path, monkeypatch, capsys):
    root = tmp_path / "ds"
    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(root), *SMALL, "--workers", "2", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["cases"] == 3 and summary["generated"] == 3 and summary["failed"] == 0
    assert summary["frames_generated"] == 9 and summary["frames_per_second"] > 0
    assert any("one physical case" in n for n in summary["notes"])

    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(root), *SMALL, "--json")
    assert code == 0 and json.loads(out)["skipped"] == 3

    png = tmp_path / "alpha.png"
    code, out, err = run_main(monkeypatch, capsys, "dataset", "info", str(root), "--plot", str(png), "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["cases"] == 3 and info["frames"] == 9
    assert info["cases_by_split"] == {"train": 2, "validation": 1}
    assert len(info["removed_fraction_per_frame"]) == 3 and info["removed_fraction_per_frame"][0] == 0.0
    assert info["peeq_range"][0] == 0.0 and info["von_mises_range_pa"][1] > 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert info["size_mb"] > 0 and info["worker_hours"] > 0
    assert {k: g["cases"] for k, g in info["solver_rates"].items()} == {"0/230": 1, "30/230": 2}

    code, out, err = run_main(monkeypatch, capsys, "dataset", "info", str(root))  # rich table
    assert code == 0 and "removed fraction" in out and "γ 30°, 230 N" in out

    # without --json, every finished case gets its own line: a sweep logged to a file shows progress
    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(tmp_path / "logged"), *SMALL)
    assert code == 0, err
    lines = [line for line in err.splitlines() if "tets removed" in line]
    assert len(lines) == 3 and any(line.startswith("g030.0_t090.0_f230N: 3 frames recorded, completed, ") for line in lines)

    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(tmp_path / "plan"), "--dry-run", "--json")
    plan = json.loads(out)
    assert plan["cases"] == 60 and not (tmp_path / "plan").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--inclinations", "95"], "inclinations must lie in [0, 90]"),
        (["--anteversions", "0:90:-15"], "positive step"),
        (["--inclinations", "none"], "empty list"),
        (["--frames", "0"], "--frames"),
        (["--scheduler", "tcp://127.0.0.1:9", "--connect-timeout", "1"], "cannot reach the Dask scheduler"),
    ],
)
def test_dataset_bad_input(tmp_path, monkeypatch, capsys, args, message):
    base = [a for a in SMALL]
    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(tmp_path / "ds"), *base, *args)
    assert code == 2 and out == ""
    assert err.startswith("thrsim: error:") and message in err and err.count("\n") == 1
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize("obstacle", ["dangling link", "file"])
def test_dataset_out_that_cannot_be_created_is_refused_by_dry_run_and_run(tmp_path, monkeypatch, capsys, obstacle):
    """A fresh clone once held `data` as a link to another machine's folder: `--out data/default`
    must fail with the one-line error, and `--dry-run` must say so rather than approve the plan."""
    monkeypatch.chdir(tmp_path)
    if obstacle == "dangling link":
        (tmp_path / "data").symlink_to(tmp_path / "elsewhere" / "thrsim-data")
    else:
        (tmp_path / "data").write_text("not a folder")
    for extra in (["--dry-run"], []):
        code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", "data/default", *SMALL, *extra)
        assert code == 2 and out == "", (extra, err)
        assert err.startswith("thrsim: error: data/default: cannot create the dataset folder: data is ") and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]


def test_dataset_dry_run_refuses_what_the_run_refuses(tmp_path, monkeypatch, capsys):
    root = tmp_path / "ds"
    assert run_main(monkeypatch, capsys, "dataset", "--out", str(root), *SMALL, "--json")[0] == 0
    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(root), *SMALL, "--frames", "5", "--dry-run")
    assert code == 2 and "different configuration" in err


@pytest.mark.parametrize("extra", [["--dry-run"], []])
def test_dataset_solver_is_one_of_thrsims_own_and_no_module_is_imported(tmp_path, monkeypatch, capsys, extra):
    marker = tmp_path / "imported"
    (tmp_path / "not_thrsim_solver.py").write_text(f"open({str(marker)!r}, 'w').close()\ndef run(case, out):\n    return {{}}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    args = [a for a in SMALL if a not in ("--solver", "synthetic")]
    for solver in ("not_thrsim_solver:run", "os:system", "nope"):
        code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(tmp_path / "ds"), *args, "--solver", solver, *extra)
        assert code == 2 and out == "" and err == f"thrsim: error: --solver must be one of fem, synthetic, got {solver!r}\n"
    assert not marker.exists() and not (tmp_path / "ds").exists()


def test_dataset_solver_choices_are_the_named_solvers():
    from thrsim.cli.dataset_cmd import _SOLVER_CHOICES
    from thrsim.data.generate import SOLVERS

    assert set(_SOLVER_CHOICES) == set(SOLVERS)


def test_dataset_config_sets_every_case_and_names_the_folder(tmp_path, monkeypatch, capsys):
    wider = tmp_path / "wider.json"
    wider.write_text(json.dumps({"bone": {"half_angle_deg": 30.0}, "damage": {"displacement_at_failure_m": 3e-4}}))
    root = tmp_path / "ds"
    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(root), *SMALL, "--config", str(wider), "--json")
    assert code == 0, err
    for entry in read_manifest(root)["cases"].values():
        with h5py.File(root / entry["file"]) as case:
            config = json.loads(case.attrs["config"])
        assert config["bone"]["half_angle_deg"] == 30.0 and config["damage"]["displacement_at_failure_m"] == 3e-4
    # the same folder without the file is another configuration: refused, nothing touched
    before = {p: p.stat().st_mtime_ns for p in root.rglob("*")}
    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(root), *SMALL)
    assert code == 2 and "different configuration" in err and "half_angle_deg" in err
    assert {p: p.stat().st_mtime_ns for p in root.rglob("*")} == before


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "no such configuration file"),
        ("{not json", "not valid JSON"),
        ('{"inclination_deg": 10, "frames": 4}', "inclination_deg, frames are set by the sweep's own flags"),
        ('{"material": {"density_kg_m3": -1}}', "density_kg_m3"),
    ],
)
def test_dataset_bad_config(tmp_path, monkeypatch, capsys, content, message):
    config = tmp_path / "case.json"
    if content is not None:
        config.write_text(content)
    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(tmp_path / "ds"), *SMALL, "--config", str(config))
    assert code == 2 and out == "" and message in err and err.count("\n") == 1
    assert not (tmp_path / "ds").exists()


def test_dataset_refuses_other_configuration_and_missing_out(tmp_path, monkeypatch, capsys):
    root = tmp_path / "ds"
    assert run_main(monkeypatch, capsys, "dataset", "--out", str(root), *SMALL, "--json")[0] == 0
    before = {p: p.stat().st_mtime_ns for p in root.rglob("*")}
    code, out, err = run_main(
        monkeypatch, capsys, "dataset", "--out", str(root), *SMALL[:-4], "--frames", "5", "--extra-forces", "none", "--solver", "synthetic"
    )
    assert code == 2 and "different configuration" in err and "frames" in err
    assert {p: p.stat().st_mtime_ns for p in root.rglob("*")} == before
    code, out, err = run_main(monkeypatch, capsys, "dataset", *SMALL)
    assert code == 2 and "--out" in err
    code, out, err = run_main(monkeypatch, capsys, "dataset", "info", str(tmp_path / "nothing"))
    assert code == 2 and "no such dataset" in err


def _children(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def test_kill9_parent_then_resume(tmp_path):
    root = tmp_path / "ds"
    cmd = [
        *THRSIM,
        "dataset",
        "--out",
        str(root),
        "--inclinations",
        "0,15,30",
        "--anteversions",
        "0,90",
        "--frames",
        "3",
        "--extra-forces",
        "none",
        "--solver",
        "synthetic",
        "--workers",
        "2",
        "--json",
    ]
    env = checkout_env(THRSIM_SYNTHETIC_SECONDS_PER_FRAME="0.4")
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 60
    workers: list[int] = []
    while time.time() < deadline:
        workers = sorted(set(workers) | set(_children(proc.pid)))
        manifest = read_manifest(root) if (root / "manifest.json").exists() else None
        if manifest and any(e["status"] == "complete" for e in manifest["cases"].values()):
            break
        time.sleep(0.05)
    else:
        proc.kill()
        pytest.fail("no case completed in time")
    done_before = sum(e["status"] == "complete" for e in read_manifest(root)["cases"].values())
    assert done_before < 5
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    # the pool's workers die with their parent (PR_SET_PDEATHSIG)
    for _ in range(100):
        alive = [w for w in workers if Path(f"/proc/{w}").exists() and "Z" not in Path(f"/proc/{w}/stat").read_text().split()[2]]
        if not alive:
            break
        time.sleep(0.05)
    assert not alive
    assert len(workers) >= 2, "the pool's worker processes were not seen"

    again = subprocess.run(cmd, env=checkout_env(), capture_output=True, text=True, timeout=90)
    assert again.returncode == 0, again.stderr
    summary = json.loads(again.stdout)
    assert summary["cases"] == 5 and summary["failed"] == 0
    assert summary["skipped"] + summary["adopted"] >= done_before
    assert summary["skipped"] + summary["adopted"] + summary["generated"] == 5
    manifest = read_manifest(root)
    assert all(e["status"] == "complete" for e in manifest["cases"].values())
    assert sorted(p.name for p in (root / "cases").iterdir()) == sorted(f"{c}.h5" for c in manifest["cases"])
    for entry in manifest["cases"].values():
        validate_case(root / entry["file"])
