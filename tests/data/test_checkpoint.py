"""Long cases checkpoint and resume: a case interrupted after a checkpoint ends as the uninterrupted one, bit for bit."""

from __future__ import annotations

import json
import signal
import subprocess
import time

import h5py
import numpy as np
from checkout_cli import THRSIM, checkout_env, run_thrsim

from thrsim.config import BonePatchConfig, ReamingCaseConfig
from thrsim.data.case_file import validate_case
from thrsim.data.checkpoint import checkpoint_path, checkpointed_frames
from thrsim.data.ground_truth import run_case
from thrsim.physics.explicit import SolidArrays
from thrsim.physics.reaming_case import SOLID_STATE

#: a coarse patch pushed hard: it cuts within a few frames
CASE = ReamingCaseConfig(inclination_deg=15, anteversion_deg=30, frames=4, force_n=460, bone=BonePatchConfig(element_size_mm=1.6))
FEM = ["fem", "--inclination", "15", "--anteversion", "30", "--force", "460", "--element-size", "1.6"]


def test_a_checkpoint_keeps_every_state_array():
    """Every field of the solid's arrays is state a checkpoint keeps, or built again from the mesh and the zone:
    a new state field must be added to SOLID_STATE (a resumed case would silently differ)."""
    rebuilt = {
        "tets", "zone_elements", "zone_nodes", "contact_nodes", "material", "grads", "volume", "char_length", "bulk_viscosity",
        "offsets", "entries", "support_stiffness", "held", "static_flow_stress", "static_flow_peeq",
    }  # fmt: skip
    assert set(SolidArrays._fields) - set(SOLID_STATE) == rebuilt and set(SOLID_STATE) <= set(SolidArrays._fields)


def _frames(path) -> dict[str, np.ndarray]:
    with h5py.File(path, "r") as f:
        return {name: f["frames"][name][()] for name in f["frames"]}


def test_a_case_resumed_from_its_checkpoint_is_the_uninterrupted_case(tmp_path):
    whole, part = tmp_path / "whole.h5", tmp_path / "part.h5"
    run_case(CASE, whole)

    class Crash(Exception):
        pass

    def crash_after_two(done: int, total: int) -> None:
        if done == 2:
            raise Crash

    checkpoint = checkpoint_path(part)
    try:
        run_case(CASE, part, progress=crash_after_two, checkpoint=checkpoint, checkpoint_every_s=0)
    except Crash:
        pass
    assert checkpointed_frames(checkpoint) == 2 and not part.exists()
    summary = run_case(CASE, part, checkpoint=checkpoint, checkpoint_every_s=0)
    assert summary["resumed_from_frame"] == 2 and not checkpoint.exists()
    expected, resumed = _frames(whole), _frames(part)
    assert expected.keys() == resumed.keys() and (expected["status"][-1] == 0).sum() > 0
    for name, values in expected.items():
        assert np.array_equal(values, resumed[name]), name
    # a checkpoint of another case (another push) is not resumed: that case starts from frame 0
    other = CASE.model_copy(update={"force_n": 300.0})
    try:
        run_case(CASE, part, progress=crash_after_two, checkpoint=checkpoint, checkpoint_every_s=0)
    except Crash:
        pass
    assert run_case(other, tmp_path / "other.h5", checkpoint=checkpoint)["resumed_from_frame"] is None


def test_thrsim_fem_killed_resumes_where_it_checkpointed(tmp_path):
    out = tmp_path / "case.h5"
    args = [*FEM, "--frames", "6", "--checkpoint-every", "0", "--out", str(out), "--json"]
    running = subprocess.Popen([*THRSIM, *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=checkout_env())
    checkpoint = checkpoint_path(out)
    try:
        deadline = time.monotonic() + 900
        while (checkpointed_frames(checkpoint) or 0) < 2 and running.poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        running.send_signal(signal.SIGKILL)
        running.wait()
    kept = checkpointed_frames(checkpoint)
    assert kept is not None and kept >= 2 and not out.exists()
    done = run_thrsim(*args, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads(done.stdout)
    assert summary["resumed_from_frame"] == kept and summary["frames"] == 6
    assert validate_case(out)["frames"] == 7 and not checkpoint.exists()
