"""Aiming ``thrsim ream`` and ``thrsim fem``: the bone frame's γ/θ or the clinical cup angles, one pair;
refusals are one line naming the flags, before anything runs."""

from __future__ import annotations

import json

import h5py
import pytest

from thrsim.nav.bone_frame import bone_angles_from_cup


@pytest.mark.parametrize("command", [["ream", "--out", "r"], ["fem", "--out", "c.h5"]])
@pytest.mark.parametrize(
    "args, message",
    [
        (["--inclination", "10", "--anteversion", "0", "--cup-inclination", "40", "--cup-anteversion", "15"], "not both"),
        (["--anteversion", "0", "--cup-inclination", "40"], "not both"),
        (["--cup-inclination", "40"], "--cup-inclination and --cup-anteversion go together"),
        (["--cup-inclination", "95", "--cup-anteversion", "10"], "--cup-inclination must lie in [0, 90]"),
        (["--cup-inclination", "40", "--cup-anteversion", "-100"], "--cup-anteversion must lie in [-90, 90]"),
        (["--cup-inclination", "0", "--cup-anteversion", "-90"], "γ 105.0° from the socket axis"),
        (["--inclination", "95", "--anteversion", "0"], "--inclination must lie in [0, 90]"),
    ],
)
def test_a_wrong_aim_is_refused_in_one_line(thrsim_inprocess, tmp_path, command, args, message):
    result = thrsim_inprocess(*command, *args, cwd=tmp_path)
    assert result.returncode == 2 and message in result.stderr and result.stderr.count("\n") == 1, result.stderr
    assert list(tmp_path.iterdir()) == []


def test_fem_needs_an_aim(thrsim_inprocess, tmp_path):
    result = thrsim_inprocess("fem", "--out", "c.h5", cwd=tmp_path)
    assert result.returncode == 2 and "give the aim" in result.stderr and "--cup-inclination" in result.stderr


def test_fem_takes_clinical_cup_angles_and_stores_the_bone_frames(thrsim, tmp_path):
    out = tmp_path / "c.h5"
    result = thrsim(
        "fem", "--cup-inclination", "45", "--cup-anteversion", "20", "--frames", "1", "--element-size", "2", "--threads", "1",
        "--out", str(out), "--json", timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    gamma, theta = bone_angles_from_cup(45.0, 20.0)
    assert (summary["inclination_deg"], summary["anteversion_deg"]) == pytest.approx((gamma, theta))
    assert (summary["cup_inclination_deg"], summary["cup_anteversion_deg"]) == (45.0, 20.0)
    with h5py.File(out) as case:
        assert (case.attrs["inclination_deg"], case.attrs["anteversion_deg"]) == pytest.approx((gamma, theta))
