"""Session files (real HDF5), replay and the assessment report, from a session lived through the
real trainer; and the report/replay commands' refusals."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from app_helpers import REPO, checkout_env

from thrsim.app.live import LiveSession
from thrsim.app.modes import MODES
from thrsim.app.replay import replay_session
from thrsim.errors import ThrsimInputError
from thrsim.report import build_report
from thrsim.session import FORMAT_VERSION, read_session
from thrsim.session.navigation import read_navigation


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def live_session(folder: Path) -> Path:
    clock = FakeClock()
    session = LiveSession(MODES["navigation"], {"side": "right", "seed": 11}, clock, folder)

    def run(seconds: float) -> None:
        for _ in range(int(seconds * 60)):
            clock.now += 1 / 60
            session.tick()

    run(0.2)
    session.control({"type": "camera", "azimuth_deg": -130, "elevation_deg": 10, "distance_mm": 1600})
    run(0.5)  # a dropout by angle
    session.control({"type": "camera", "azimuth_deg": 50, "elevation_deg": -37, "distance_mm": 1600})
    for _ in range(40):
        if session.trainer.registration.done:
            break
        session.control({"type": "probe", "action": "touch"})
        run(0.7)
        if len(session.trainer.registration.acquired) == 3 and not session.trainer.log.retakes:
            session.control({"type": "registration", "action": "retake"})
    with pytest.raises(ThrsimInputError):
        session.control({"type": "reamer", "inclination_deg": 95, "anteversion_deg": 0})
    for inclination in (55, 48, 42, 40):
        session.control({"type": "reamer", "inclination_deg": inclination, "anteversion_deg": 15})
        run(0.3)
    session.control({"type": "confirm_cup"})
    pose = session.trainer.tools["Reamer"].pose.copy()
    session.pose("ReamerToReference", pose, clock.now)  # a tracker reading mid-session
    run(0.2)
    return session.save()


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> Path:
    return live_session(tmp_path_factory.mktemp("sessions"))


def test_session_file_keeps_inputs_outputs_and_versions(saved):
    session = read_session(saved)
    assert session.attrs["format"] == "thrsim-session" and session.attrs["format_version"] == FORMAT_VERSION
    assert {"thrsim", "numpy", "h5py", "fastapi", "three.js"} <= set(session.versions)
    assert session.settings == {"mode": "navigation", "side": "right", "seed": 11}
    kinds = [json.loads(m)["type"] for _, _, m in session.inputs.controls]
    assert kinds.count("probe") >= 27 and "confirm_cup" in kinds and "registration" in kinds
    assert session.inputs.pose_devices() == ["ReamerToReference"]
    times = session.inputs.tick_time.numpy(float)
    assert np.all(np.diff(times) > 0) and len(times) > 27 * 40
    record = read_navigation(session.groups["navigation"])
    assert record.completed and record.retakes.sum() == 1 and len(record.confirmations) == 1
    assert record.angles.shape == (len(times), 3) and record.tool_codes.shape == (len(times), 3)
    assert not saved.parent.joinpath(f".{saved.name}").exists() and len(list(saved.parent.iterdir())) == 1


def test_replay_reproduces_the_recorded_session(saved):
    outcome = replay_session(saved)
    assert outcome.reproduced and outcome.max_angle_difference_deg == 0.0
    assert outcome.refused_controls == 0  # the out-of-range control was refused before it was logged


def test_replay_notices_a_changed_recording(saved, tmp_path):
    changed = tmp_path / "changed.h5"
    changed.write_bytes(saved.read_bytes())
    with h5py.File(changed, "r+") as h5:
        angles = h5["navigation/trace/angles"]
        data = angles[()]
        data[-1, 0] += 1.0
        angles[...] = data
    outcome = replay_session(changed)
    assert not outcome.trace_match and not outcome.reproduced


def test_report_is_self_contained_with_plots_and_scored_criteria(saved):
    html = build_report(saved)
    assert html.count("data:image/png;base64,") >= 3
    assert not re.search(r"""(src|href)=["']?(https?:|//|/)""", html)  # nothing fetched from elsewhere
    for heading in ("Summary score", "Landmark registration", "Cup orientation against the safe zone", "Tracking dropouts"):
        assert heading in html
    for criterion in (
        "registration completed",
        "registration accuracy",
        "time in the safe zone while aiming",
        "confirmed cup orientation",
        "markers kept visible",
        "retakes",
    ):
        assert criterion in html
    score = re.search(r'class="score">([\d.]+) / ([\d.]+)<', html)
    assert score and 0 < float(score.group(1)) <= float(score.group(2)) == 100


def test_garbled_missing_and_foreign_session_files_are_refused(saved, tmp_path):
    garbled = tmp_path / "garbled.h5"
    garbled.write_bytes(saved.read_bytes()[:5000])
    with pytest.raises(ThrsimInputError, match="unreadable"):
        read_session(garbled)
    with pytest.raises(ThrsimInputError, match="no such session file"):
        read_session(tmp_path / "absent.h5")
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as h5:
        h5.attrs["format"] = "thrsim-case"
    with pytest.raises(ThrsimInputError, match="not a thrsim session"):
        read_session(other)
    newer = tmp_path / "newer.h5"
    newer.write_bytes(saved.read_bytes())
    with h5py.File(newer, "r+") as h5:
        h5.attrs["format_version"] = FORMAT_VERSION + 1
    with pytest.raises(ThrsimInputError, match="format version"):
        build_report(newer)
    broken = tmp_path / "broken.h5"
    broken.write_bytes(saved.read_bytes())
    with h5py.File(broken, "r+") as h5:
        del h5["navigation/registration"]
    with pytest.raises(ThrsimInputError, match="navigation group"):
        build_report(broken)


@pytest.mark.parametrize("column", ["inputs/controls/time", "inputs/poses/time", "inputs/ticks/time", "navigation/events/value"])
def test_session_files_with_columns_of_unequal_length_are_refused(saved, tmp_path, column):
    uneven = tmp_path / "uneven.h5"
    uneven.write_bytes(saved.read_bytes())
    with h5py.File(uneven, "r+") as h5:
        values = h5[column][()]
        assert len(values) > 0
        del h5[column]
        h5.create_dataset(column, data=values[:-1])
    with pytest.raises(ThrsimInputError, match="garble"):
        read_navigation(read_session(uneven).groups["navigation"])


def _thrsim(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "thrsim", *args], cwd=REPO, capture_output=True, text=True, timeout=120, env=checkout_env()
    )


def test_report_and_replay_commands(saved, tmp_path):
    out = tmp_path / "report.html"
    done = _thrsim("report", str(saved), "--out", str(out), "--json")
    assert done.returncode == 0, done.stderr
    assert out.read_text().startswith("<!doctype html>")
    summary = json.loads(done.stdout)
    assert summary["report"] == str(out) and 0 < summary["score"] <= summary["max_score"]
    assert summary["max_score"] == sum(c["max_points"] for c in summary["criteria"]) and summary["criteria"][0]["name"]
    replayed = _thrsim("replay", str(saved), "--json")
    assert replayed.returncode == 0 and json.loads(replayed.stdout)["reproduced"] is True


@pytest.mark.parametrize("args", [("report", "absent.h5", "--out", "r.html"), ("replay", "absent.h5")])
def test_commands_refuse_a_missing_session_in_one_line(tmp_path, args):
    done = subprocess.run(
        [sys.executable, "-m", "thrsim", *args], cwd=tmp_path, capture_output=True, text=True, timeout=120, env=checkout_env()
    )
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "no such session file" in done.stderr
    assert not (tmp_path / "r.html").exists()
