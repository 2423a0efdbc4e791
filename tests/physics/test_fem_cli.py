"""`thrsim fem` end to end: a valid case file, and refusal of bad input without partial output."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
from checkout_cli import run_main, run_thrsim

from thrsim.data.case_file import read_case, validate_case

pytestmark = pytest.mark.timeout(300)


def thrsim(*args: str) -> subprocess.CompletedProcess:
    return run_thrsim(*args, timeout=280)


def test_fem_writes_a_valid_case(tmp_path):
    out = tmp_path / "c.h5"
    result = thrsim(
        "fem",
        "--inclination",
        "15",
        "--anteversion",
        "30",
        "--frames",
        "4",
        "--force",
        "460",
        "--element-size",
        "1.2",
        "--out",
        str(out),
        "--json",
    )
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["frames"] == 4 and summary["removed"] > 0
    assert summary["seconds_per_frame"] > 0 and summary["max_kinetic_to_internal"] < 0.1
    checked = validate_case(out)
    assert checked["frames"] == 5
    case = read_case(out)
    assert case.attrs["format"] == "thrsim-case"
    axis = np.asarray(case.reamer_axis)
    moved = case.frames.reamer_position - case.frames.reamer_position[0]
    np.testing.assert_allclose(moved[-1] @ axis, summary["reamer_advance_mm"] * 1e-3, rtol=1e-6)
    np.testing.assert_allclose(np.cross(moved, axis), 0.0, atol=1e-12)  # one degree of freedom, along D
    damage, status = case.frames.damage, case.frames.status
    assert damage.shape == status.shape and damage[0].max() == 0.0 and 0.0 < damage[-1].max() <= 1.0
    assert np.all(np.diff(damage, axis=0)[status[1:] == 1] >= 0)  # damage never heals in live elements
    assert np.all(case.frames.damage_initiation >= 0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.h5"]


@pytest.mark.parametrize(
    "settings, flags, needle",
    [
        ({"material": {"density_kg_m3": -1700}}, [], "density_kg_m3"),
        ({"material": {"poisson_ratio": 0.5}}, [], "poisson_ratio"),
        ({}, ["--frames", "0"], "frames"),
        ({}, ["--inclination", "120"], "--inclination must lie in [0, 90]"),
        ({"solver": {"target_dt_s": 0}}, [], "target_dt_s"),
        ({}, ["--effective-mass", "0"], "effective_mass_kg"),
        ({}, ["--axial-damping", "-5"], "axial_damping_n_s_m"),
        ({}, ["--contact-factor", "0"], "penalty_factor"),
        ({}, ["--contact-factor", "2.5"], "stable step"),
        ({}, ["--cutting-energy", "0"], "specific_cutting_energy_j_m3"),
        ({"solver": {"safety_factor": 0.9}}, [], "stable step"),
        ({"contact": {"damping_ratio": -0.1}}, [], "damping_ratio"),
    ],
)
def test_non_physical_parameters_are_refused(tmp_path, settings, flags, needle):
    config = tmp_path / "case.json"
    config.write_text(json.dumps(settings))
    out = tmp_path / "c.h5"
    args = ["fem", "--inclination", "15", "--anteversion", "30", "--config", str(config), "--out", str(out), *flags]
    result = thrsim(*args)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in result.stderr
    assert not out.exists()


def test_unwritable_output_and_inverted_mesh_are_refused(tmp_path):
    result = thrsim("fem", "--inclination", "0", "--anteversion", "0", "--out", str(tmp_path / "missing" / "c.h5"))
    assert result.returncode == 2 and "does not exist" in result.stderr
    inp = tmp_path / "inverted.inp"
    inp.write_text(
        "*NODE\n1, 0, 0, 0\n2, 1, 0, 0\n3, 0, 1, 0\n4, 0, 0, 1\n*ELEMENT, TYPE=C3D4\n1, 1, 3, 2, 4\n*NSET, NSET=FIXED\n1, 2, 3\n"
    )
    out = tmp_path / "c.h5"
    result = thrsim("fem", "--inclination", "0", "--anteversion", "0", "--mesh", str(inp), "--out", str(out))
    assert result.returncode == 2 and "inverted" in result.stderr and str(inp) in result.stderr
    assert not out.exists()


def test_a_blow_up_stops_with_the_frame_and_writes_nothing(tmp_path, monkeypatch, capsys):
    from thrsim.physics.reaming_case import ReamingCase

    original = ReamingCase.advance

    def unstable_advance(self, steps):
        result = original(self, steps)
        self.solid.velocity[0, 0] = np.nan  # a node's velocity turns NaN during frame 1
        return result

    monkeypatch.setattr(ReamingCase, "advance", unstable_advance)
    out = tmp_path / "c.h5"
    code, _, err = run_main(
        monkeypatch,
        capsys,
        "fem",
        "--inclination",
        "15",
        "--anteversion",
        "30",
        "--frames",
        "3",
        "--element-size",
        "1.2",
        "--out",
        str(out),
    )
    assert code == 3
    assert "frame 1" in err and "non-finite" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []
