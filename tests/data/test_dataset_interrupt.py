"""`thrsim dataset` stopped by Ctrl-C or SIGTERM: gone within 2 s, its workers with it, and every
case finished before the stop in the manifest; the same command then finishes the rest."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from checkout_cli import THRSIM, checkout_env

pytestmark = pytest.mark.timeout(180)

SWEEP = ["--solver", "synthetic", "--inclinations", "15,30", "--anteversions", "0,45,90,135", "--frames", "12"]
SWEEP += ["--element-sizes", "1.0", "--extra-forces", "none", "--workers", "2", "--json"]


def statuses(out: Path) -> dict[str, str]:
    try:
        return {case_id: entry["status"] for case_id, entry in json.loads((out / "manifest.json").read_text())["cases"].items()}
    except (OSError, ValueError, KeyError):
        return {}


def running_in_group(pgid: int) -> list[int]:
    """Processes of the group that still run (zombies are not: they wait for whichever init reaps them)."""
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            pids.append(int(stat.parent.name))
    return pids


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_dataset_stops_within_2_s_and_keeps_every_finished_case(tmp_path, how):
    out = tmp_path / "data"
    # a slowed stand-in solver: about 1.8 s a case, so that cases are running when the stop comes
    env = checkout_env(THRSIM_SYNTHETIC_SECONDS_PER_FRAME="0.15")
    # a command started from an interactive shell hears Ctrl-C; one started in the background of a
    # script inherits SIGINT ignored (POSIX), as this test would if pytest itself ran so
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        sweep = subprocess.Popen(
            [*THRSIM, "dataset", *SWEEP, "--out", str(out)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True
        )
    finally:
        signal.signal(signal.SIGINT, inherited)
    try:
        deadline = time.monotonic() + 120
        while "complete" not in statuses(out).values():
            assert sweep.poll() is None and time.monotonic() < deadline, sweep.communicate()
            time.sleep(0.05)
        time.sleep(0.5)  # the other worker is mid-case
        stopped = time.monotonic()
        if how == "ctrl-c":
            os.killpg(sweep.pid, signal.SIGINT)  # a terminal sends it to the whole foreground group
        else:
            sweep.send_signal(signal.SIGTERM)  # a service manager sends it to the command
        _, err = sweep.communicate(timeout=30)
        took = time.monotonic() - stopped
    finally:
        if sweep.poll() is None:
            os.killpg(sweep.pid, signal.SIGKILL)
    stderr = err.decode()
    assert took < 2.0, f"stopped after {took:.1f} s"
    assert sweep.returncode == (130 if how == "ctrl-c" else 143), stderr
    assert "Traceback" not in stderr and "manifest.json" in stderr.strip().splitlines()[-1]
    for _ in range(20):  # the workers went with it
        if not running_in_group(sweep.pid):
            break
        time.sleep(0.05)
    assert running_in_group(sweep.pid) == []
    finished = {p.name.removesuffix(".h5") for p in (out / "cases").glob("*.h5")}
    recorded = statuses(out)
    assert finished and all(recorded[case_id] == "complete" for case_id in finished), (finished, recorded)
    assert set(recorded.values()) <= {"complete", "pending"}  # the cases cut short are to be run, not failed
    assert [p.name for p in (out / "cases").iterdir() if p.name.endswith((".part", ".tmp"))] == []

    again = subprocess.run([*THRSIM, "dataset", *SWEEP, "--out", str(out)], env=checkout_env(), capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    summary = json.loads(again.stdout)
    assert summary["skipped"] == len(finished) and summary["generated"] == 8 - len(finished)
