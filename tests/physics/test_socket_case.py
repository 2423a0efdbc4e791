"""A reaming case on the layered socket: sizes, pre-ream, materials, the force and torque the surgeon feels."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from checkout_cli import run_thrsim

from thrsim.config import ReamerConfig, ReamingCaseConfig, SocketConfig, head_diameter_for_size, teeth_for_diameter
from thrsim.physics.reaming_case import ReamingCase

#: a coarse socket: seconds to mesh, enough elements to ream
COARSE = ["--bone", "socket", "--element-size", "2.5"]


def test_a_reamer_one_size_up_reams_the_native_socket(tmp_path):
    out = tmp_path / "socket.h5"
    result = run_thrsim(
        "fem", *COARSE, "--reamer-diameter", "48", "--inclination", "0", "--anteversion", "0", "--frames", "2",
        "--out", str(out), "--json", timeout=900,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    summary = json.loads(result.stdout)
    assert summary["bone"] == "socket" and summary["reamer_diameter_mm"] == pytest.approx(48.0)
    assert summary["reamer_teeth"] == teeth_for_diameter(head_diameter_for_size(48.0))
    assert set(summary["removed_volume_by_material_mm3"]) == {"cortical", "cancellous"}
    assert summary["first_contact_frame"] == 1 and summary["end_reason"] in ("completed", "stalled")
    with h5py.File(out, "r") as f:
        assert json.loads(f["mesh/material"].attrs["names"]) == ["cortical", "cancellous"]
        assert set(np.unique(f["mesh/material"][()])) == {0, 1}
        reaction, torque = f["frames/reaction_force"][()], f["frames/motor_torque"][()]
        axis = f["frames/reamer_axis"][()]
        assert reaction.shape == (f["frames/time"].shape[0], 3) and torque.shape == (reaction.shape[0],)
        assert np.all(reaction[0] == 0) and torque[0] == 0
        # once seated on the rim the bone pushes back against the feed, and the motor works to turn the teeth
        assert reaction[-1] @ axis < 0 and torque[-1] > 0
        assert f.attrs["bone"] == "socket" and f.attrs["reamer_diameter_mm"] == pytest.approx(48.0)
        cancellous, kept = f["mesh/material"][()] == 1, f["frames/status"][-1] == 1
        crushed = cancellous & kept & (f["frames/peeq"][-1] > 0.42)  # past eq. 47's threshold by its strain alone
    # the rim's crush compacts the cancellous bone behind it: crushed bone stays, and the labels a model learns keep it
    from thrsim.learn.cases import load_cases

    _, (case,) = load_cases(out)
    assert crushed.any() and not (case.alpha[-1] < 0.3)[crushed].any() and case.bone_kind == "socket"
    # a socket case is scored by the shipped socket model unless another is named
    scored = run_thrsim("evaluate", "--data", str(out), "--json", timeout=600)
    assert scored.returncode == 0, scored.stderr[-2000:]
    assert json.loads(scored.stdout)["model"]["path"].endswith("socket") and "48" in json.loads(scored.stdout)


def test_a_pre_reamed_socket_starts_from_its_cavity():
    socket = SocketConfig(element_size_mm=2.5)
    case = ReamingCaseConfig(
        inclination_deg=0, anteversion_deg=0, bone_kind="socket", socket=socket, pre_ream_mm=48.0,
        reamer=ReamerConfig(head_diameter_mm=head_diameter_for_size(50.0)), frames=1,
    )  # fmt: skip
    simulation = ReamingCase(case)
    radius = np.linalg.norm(simulation.mesh.centroids, axis=1)
    assert simulation.prepared.sum() > 50
    assert np.all(radius[simulation.prepared] < 24e-3) and not np.any(simulation.solid.active[radius < 24e-3])
    # the reamer starts clear of what is left, nearer than it would over the native socket
    clear = np.linalg.norm(simulation.mesh.nodes[simulation.solid.alive_nodes] - simulation.centre, axis=1)
    assert clear.min() >= simulation.reamer.outer_radius


@pytest.mark.parametrize(
    "args, says",
    [
        (("--reamer-diameter", "44", "--pre-ream", "46"), "smaller than the 46 mm prepared cavity"),
        (("--reamer-diameter", "60", "--pre-ream", "58"), "beyond the bone stock"),
        (("--cancellous", "spongy"), "--cancellous must be one of"),
        (("--pre-ream-centre", "1,2"), "--pre-ream-centre must be three numbers"),
    ],
)
def test_bad_socket_cases_are_refused(tmp_path, args, says):
    out = tmp_path / "case.h5"
    result = run_thrsim("fem", *COARSE, "--inclination", "0", "--anteversion", "0", *args, "--out", str(out))
    assert result.returncode == 2 and says in result.stderr and "Traceback" not in result.stderr
    assert not out.exists()


def test_socket_options_on_the_patch_are_refused(tmp_path):
    out = tmp_path / "case.h5"
    result = run_thrsim("fem", "--inclination", "0", "--anteversion", "0", "--pre-ream", "46", "--out", str(out))
    assert result.returncode == 2 and "socket" in result.stderr and not out.exists()


def test_a_chain_of_sizes_carries_the_bone_and_refuses_another_mesh(tmp_path):
    first, second = tmp_path / "r48.h5", tmp_path / "r50.h5"
    common = ["--inclination", "0", "--anteversion", "0", "--frames", "1", "--json"]
    done = run_thrsim("fem", *COARSE, "--reamer-diameter", "48", *common, "--out", str(first), timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    chained = run_thrsim("fem", *COARSE, "--reamer-diameter", "50", "--start-from", str(first), *common, "--out", str(second), timeout=900)
    assert chained.returncode == 0, chained.stderr[-2000:]
    with h5py.File(first, "r") as f:
        removed_before = f["frames/status"][-1] == 0
        damage_before = f["frames/damage"][-1]
    with h5py.File(second, "r") as f:
        start = f["frames/status"][0]
        assert f.attrs["start_from"] and len(f.attrs["start_from"]) == 64
        # what the 48 mm reamer took is gone from frame 0 of the 50 mm case; what it damaged stays damaged
        assert removed_before.sum() > 0 and np.array_equal(start == 0, removed_before)
        kept = ~removed_before
        assert np.array_equal(f["frames/damage"][0][kept], damage_before[kept])
    other_mesh = run_thrsim(
        "fem", "--bone", "socket", "--element-size", "3", "--reamer-diameter", "50", "--start-from", str(first), *common,
        "--out", str(tmp_path / "other.h5"),
    )  # fmt: skip
    assert other_mesh.returncode == 2 and "mesh is not this case's" in other_mesh.stderr
    assert not (tmp_path / "other.h5").exists()


def test_feed_control_advances_at_the_set_rate_and_records_the_push(tmp_path):
    out = tmp_path / "feed.h5"
    done = run_thrsim(
        "fem", *COARSE, "--reamer-diameter", "48", "--inclination", "0", "--anteversion", "0", "--feed", "6", "--frames", "2",
        "--out", str(out), "--json", timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads(done.stdout)
    simulated_s = 2 * summary["steps_per_frame"] * summary["dt_s"]  # whole steps: a frame is 4167 × 4 µs
    assert summary["feed_mm_s"] == 6.0 and summary["reamer_advance_mm"] == pytest.approx(6.0 * simulated_s, rel=1e-6)
    with h5py.File(out, "r") as f:
        push, reaction, axis = f["frames/push_force"][()], f["frames/reaction_force"][()], f["frames/reamer_axis"][()]
    # the push a feed takes balances the bone's reaction along the axis, less the head's weight, in every frame
    balance = push[1:] + reaction[1:] @ axis
    assert push[0] == 0 and np.ptp(balance) < 1e-9 * max(1.0, np.abs(push).max())
    assert -5.0 < balance[0] < 0.0  # the head's weight helps a reamer pointing down: a couple of newtons


def test_a_medialised_reamer_moves_along_its_line_and_a_window_reams_its_wall(tmp_path):
    """``--reamer-centre`` puts the reamer's axis through a point of the bone frame: every recorded centre
    lies on that line; on a window of the wall the reamer cuts it and nothing else perforates."""
    out = tmp_path / "window.h5"
    done = run_thrsim(
        "fem", *COARSE, "--window", "0,90,15", "--reamer-diameter", "48", "--reamer-centre", "0,-1.5,-1",
        "--inclination", "10", "--anteversion", "90", "--feed", "30", "--frames", "3", "--out", str(out), "--json", timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads(done.stdout)
    assert summary["end_reason"] == "completed" and summary["removed"] > 0
    with h5py.File(out, "r") as f:
        centres, axis = f["frames/reamer_position"][()], f["frames/reamer_axis"][()]
        config = json.loads(f.attrs["config"])
        assert config["socket"]["window_polar_deg"] == 0.0 and config["reamer_centre_mm"] == [0.0, -1.5, -1.0]
    off_line = (centres - np.array([0.0, -1.5e-3, -1.0e-3])) - ((centres - np.array([0.0, -1.5e-3, -1.0e-3])) @ axis)[:, None] * axis
    assert np.abs(off_line).max() < 1e-12
    on_patch = run_thrsim("fem", "--inclination", "0", "--anteversion", "0", "--reamer-centre", "0,0,1", "--out", str(tmp_path / "p.h5"))
    assert on_patch.returncode == 2 and "--bone socket" in on_patch.stderr and not (tmp_path / "p.h5").exists()
