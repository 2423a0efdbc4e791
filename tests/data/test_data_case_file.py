"""The case file: layout, round trip, streaming, validation, checksums."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from thrsim.config import ReamingCaseConfig
from thrsim.data.case_file import (
    CaseFrames,
    CaseReader,
    data_digest,
    file_sha256,
    read_case,
    validate_case,
    write_case,
)
from thrsim.data.synthetic import block_mesh, synthetic_run_case
from thrsim.errors import ThrsimInputError


def _frames(mesh, t=3):
    e = mesh.n_tets
    status = np.ones((t, e), dtype=np.uint8)
    peeq = np.zeros((t, e), dtype=np.float32)
    for k in range(1, t):
        peeq[k] = peeq[k - 1] + 0.1 * (np.arange(e) % 3 == 0)
        status[k] = status[k - 1]
        status[k, :k] = 0
    vm = np.full((t, e), 1e6, dtype=np.float32)
    return CaseFrames(
        time=np.arange(t) / 60.0,
        status=status,
        peeq=peeq,
        von_mises=vm,
        reamer_position=np.zeros((t, 3)) + [0, 0, -0.02],
        energy=np.ones((t, 2)),
        energy_names=("kinetic", "internal"),
    )


def _write(path, mesh=None, frames=None, **extra):
    mesh = mesh or block_mesh(3)
    frames = frames or _frames(mesh)
    return write_case(
        path,
        mesh,
        frames,
        (0.0, 0.0, -1.0),
        inclination_deg=15.0,
        anteversion_deg=30.0,
        force_n=230.0,
        omega_rad_s=136.0,
        frame_dt_s=1 / 60,
        config={"a": 1, "nested": {"b": [1, 2]}},
        extra_attrs=extra or None,
    )


def test_layout_matches_spec(tmp_path):
    path = _write(tmp_path / "c.h5", end_reason="frames", perforated_frame=None, seconds_per_frame=0.5, stats={"x": 1})
    assert [p.name for p in tmp_path.iterdir()] == ["c.h5"]  # no temporary left behind
    mesh = block_mesh(3)
    with h5py.File(path) as f:
        assert f.attrs["format"] == "thrsim-case"
        assert int(f.attrs["version"]) == 1
        for key in ("inclination_deg", "anteversion_deg", "force_n", "omega_rad_s", "frame_dt_s", "config_hash"):
            assert key in f.attrs
        assert json.loads(f.attrs["config"]) == {"a": 1, "nested": {"b": [1, 2]}}
        assert json.loads(f.attrs["versions"])["thrsim"]
        assert f.attrs["end_reason"] == "frames" and json.loads(f.attrs["stats"]) == {"x": 1}
        assert f["mesh/nodes"].dtype == np.float64 and f["mesh/nodes"].shape == (mesh.n_nodes, 3)
        assert f["mesh/tets"].dtype == np.int32 and f["mesh/fixed_nodes"].dtype == np.int32
        e = mesh.n_tets
        assert f["frames/status"].dtype == np.uint8 and f["frames/status"].shape == (3, e)
        for name in ("status", "peeq", "von_mises"):
            assert f["frames"][name].chunks == (1, e)
            assert f["frames"][name].compression == "gzip"
        assert f["frames/peeq"].dtype == np.float32 and f["frames/von_mises"].dtype == np.float32
        assert f["frames/reamer_position"].shape == (3, 3) and f["frames/reamer_axis"].shape == (3,)
        assert list(f["frames/energy"].attrs["names"]) == ["kinetic", "internal"]


def test_round_trip_and_streaming(tmp_path):
    mesh = block_mesh(3)
    frames = _frames(mesh, t=4)
    path = _write(tmp_path / "c.h5", mesh=mesh, frames=frames)
    case = read_case(path)
    np.testing.assert_array_equal(case.mesh.tets, mesh.tets)
    np.testing.assert_array_equal(case.mesh.fixed_nodes, mesh.fixed_nodes)
    np.testing.assert_array_equal(case.frames.status, frames.status)
    np.testing.assert_array_equal(case.frames.peeq, frames.peeq)
    assert case.frames.energy_names == ("kinetic", "internal")
    assert case.attrs["config"] == {"a": 1, "nested": {"b": [1, 2]}}
    with CaseReader(path) as reader:
        assert (reader.n_frames, reader.n_elements) == (4, mesh.n_tets)
        np.testing.assert_array_equal(reader.frame(2)["status"], frames.status[2])
        with pytest.raises(IndexError):
            reader.frame(4)
    summary = validate_case(path)
    assert summary["frames"] == 4 and summary["elements"] == mesh.n_tets and summary["removed"] == 3
    assert summary["removed_per_frame"] == [0, 1, 2, 3]


def test_damage_is_optional_and_round_trips(tmp_path):
    mesh = block_mesh(3)
    frames = _frames(mesh, t=4)
    assert read_case(_write(tmp_path / "without.h5", mesh=mesh, frames=frames)).frames.damage is None  # as solvers before 0.3.1 wrote
    frames.damage = np.minimum(1.0, frames.peeq * 2).astype(np.float32)
    frames.damage_initiation = (frames.peeq * 5).astype(np.float32)
    path = _write(tmp_path / "with.h5", mesh=mesh, frames=frames)
    case = read_case(path)
    np.testing.assert_array_equal(case.frames.damage, frames.damage)
    np.testing.assert_array_equal(case.frames.damage_initiation, frames.damage_initiation)
    with h5py.File(path) as f:
        assert f["frames/damage"].dtype == np.float32 and f["frames/damage"].chunks == (1, mesh.n_tets)
    with CaseReader(path) as reader:
        np.testing.assert_array_equal(reader.frame(2)["damage"], frames.damage[2])
    assert validate_case(path)["frames"] == 4
    for mutate, message in (
        (lambda f: f["frames/damage"].__setitem__((2, 3), 1.5), "damage outside"),
        (lambda f: f["frames/damage"].__setitem__((3, 3), 0.0), "damage decreases"),
        (lambda f: f["frames/damage_initiation"].__setitem__((1, 3), np.nan), "damage_initiation outside"),
    ):
        bad = _write(tmp_path / "bad.h5", mesh=mesh, frames=frames)
        _corrupt(bad, mutate)
        with pytest.raises(ThrsimInputError, match=message):
            validate_case(bad)
        bad.unlink()


def test_checksums(tmp_path):
    a = _write(tmp_path / "a.h5", seconds_per_frame=1.0)
    b = _write(tmp_path / "b.h5", seconds_per_frame=2.0)
    assert len(file_sha256(a)) == 64
    assert file_sha256(a) != file_sha256(b)  # attrs differ
    assert data_digest(a) == data_digest(b)  # datasets identical


def test_synthetic_solver_writes_a_valid_case(tmp_path):
    summary = synthetic_run_case(ReamingCaseConfig(inclination_deg=30, anteversion_deg=45, frames=5), tmp_path / "s.h5")
    checked = validate_case(tmp_path / "s.h5")
    assert checked["frames"] == summary["frames"] == 5
    assert checked["removed"] == summary["removed"] > 0


def test_synthetic_summary_is_read_from_its_frames(tmp_path):
    """The stand-in's kinetic ÷ internal is what its energy frames say, and follows the case
    (a lighter reamer head moves with less kinetic energy), not a constant."""
    ratios = []
    for density in (7800.0, 2000.0):
        config = ReamingCaseConfig(inclination_deg=15, anteversion_deg=30, frames=6, reamer={"density_kg_m3": density})
        summary = synthetic_run_case(config, tmp_path / f"s{density:g}.h5")
        case = read_case(tmp_path / f"s{density:g}.h5")
        names = list(case.frames.energy_names)
        kinetic, internal = case.frames.energy[1:, names.index("kinetic")], case.frames.energy[1:, names.index("internal")]
        assert summary["max_kinetic_to_internal"] == pytest.approx(float(np.max(kinetic / internal)))
        ratios.append(summary["max_kinetic_to_internal"])
    assert ratios[1] == pytest.approx(ratios[0] * 2000.0 / 7800.0)


def _corrupt(path, fn):
    with h5py.File(path, "a") as f:
        fn(f)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda f: f.attrs.__setitem__("format", "other"), "not a thrsim case file"),
        (lambda f: f.__delitem__("frames/peeq"), "missing dataset /frames/peeq"),
        (lambda f: f.__delitem__("mesh/fixed_nodes"), "missing dataset /mesh/fixed_nodes"),
        (lambda f: (f.__delitem__("frames/time"), f["frames"].create_dataset("time", data=np.arange(5.0))), "has shape"),
        (lambda f: f["frames/peeq"].__setitem__((2, 1), np.nan), "NaN"),
        (lambda f: f["frames/reamer_position"].__setitem__((1, 0), np.inf), "NaN or infinite"),
        (lambda f: f["frames/status"].__setitem__((2, 0), 1), "reappear"),
        (lambda f: f["frames/peeq"].__setitem__((2, 3), 0.0), "PEEQ decreases"),
        (lambda f: f["frames/status"].__setitem__((0, 5), 0), "frame 0 is not intact"),
        (lambda f: f["frames/peeq"].__setitem__((0, 5), 0.5), "frame 0 is not intact"),
        (lambda f: f["frames/time"].__setitem__(2, 0.0), "not strictly increasing"),
        (lambda f: f["frames/energy"].attrs.__setitem__("names", ["a", "b"]), "lacks kinetic"),
    ],
)
def test_validate_refuses(tmp_path, mutate, message):
    path = _write(tmp_path / "bad.h5")
    validate_case(path)
    _corrupt(path, mutate)
    with pytest.raises(ThrsimInputError) as info:
        validate_case(path)
    assert str(path) in str(info.value) and message in str(info.value)


def test_validate_refuses_non_hdf5_and_missing(tmp_path):
    (tmp_path / "x.h5").write_bytes(b"not hdf5")
    with pytest.raises(ThrsimInputError, match="not a readable HDF5"):
        validate_case(tmp_path / "x.h5")
    with pytest.raises(ThrsimInputError, match="no such file"):
        validate_case(tmp_path / "none.h5")


def test_write_refuses_inconsistent_frames(tmp_path):
    mesh = block_mesh(3)
    frames = _frames(mesh)
    frames.peeq = frames.peeq[:, :-1]
    with pytest.raises(ThrsimInputError, match="peeq"):
        _write(tmp_path / "c.h5", mesh=mesh, frames=frames)
    frames = _frames(mesh)
    frames.energy_names = ("kinetic", "plastic")
    with pytest.raises(ThrsimInputError, match="internal"):
        _write(tmp_path / "c.h5", mesh=mesh, frames=frames)
    assert list(tmp_path.iterdir()) == []
