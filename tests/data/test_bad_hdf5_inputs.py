"""Malformed HDF5 inputs and manifests through the real command: one line on stderr, exit 2, nothing
written, never a traceback (issue 27, item 6). Each dataset's dtype, shape and size is checked
before it is read whole: a small file can declare gigabytes, hold strings where indices belong,
a group where a dataset belongs, or int64 indices that int32 would wrap."""

from __future__ import annotations

import json
import shutil
import sys

import h5py
import numpy as np
import pytest
from checkout_cli import run_main

from thrsim.cli import main

NODES = np.array([[0.0, 0.0, 0.0], [1e-3, 0.0, 0.0], [0.0, 1e-3, 0.0], [0.0, 0.0, 1e-3]])
TETS = np.array([[0, 1, 2, 3]], dtype=np.int32)


def _mesh_file(path, nodes=NODES, tets=TETS, extra=None) -> None:
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "thrsim-mesh"
        g = f.create_group("mesh")
        for name, data in (("nodes", nodes), ("tets", tets)):
            if isinstance(data, str) and data == "group":
                g.create_group(name)
            elif isinstance(data, str) and data == "huge":
                g.create_dataset(name, shape=(400_000_000, 3), dtype="f8", chunks=(1024, 3))  # 8.9 GiB declared, nothing written
            else:
                g.create_dataset(name, data=data)
        if extra:
            extra(g)


BAD_MESHES = {
    "huge_nodes": ({"nodes": "huge"}, "8.9 GiB"),
    "string_tets": ({"tets": np.array([[b"a", b"b", b"c", b"d"]])}, "/mesh/tets has dtype |S1, expected integers"),
    "group_for_nodes": ({"nodes": "group"}, "/mesh/nodes is a group, expected a dataset"),
    "tets_beyond_int32": ({"tets": np.array([[2**32, 1, 2, 3]], dtype=np.int64)}, "4294967296, beyond the int32"),
    "scalar_nodes": ({"nodes": np.float64(1.0)}, "/mesh/nodes has shape (), expected (n, 3)"),
    "node_sets_dataset": ({"extra": lambda g: g.create_dataset("node_sets", data=[1, 2])}, "node_sets is a dataset"),
}


@pytest.mark.parametrize("case", sorted(BAD_MESHES))
def test_a_malformed_hdf5_mesh_is_one_line(case, tmp_path, monkeypatch, capsys):
    spoil, needle = BAD_MESHES[case]
    _mesh_file(tmp_path / "bad.h5", **spoil)
    code, out, err = run_main(monkeypatch, capsys, "mesh", "--from", str(tmp_path / "bad.h5"), "--out", str(tmp_path / "out.vtu"), "--json")
    assert code == 2 and out == "" and "Traceback" not in err, (code, err)
    assert len(err.splitlines()) == 1 and needle in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.h5"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("bad-inputs") / "ds"
    sweep = ["--inclinations", "15", "--anteversions", "0,45,90", "--frames", "6", "--extra-forces", "none"]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(
            sys, "argv", ["thrsim", "dataset", "--out", str(root), *sweep, "--solver", "synthetic", "--element-sizes", "1.0", "--json"]
        )
        with pytest.raises(SystemExit) as exit_:
            main()
    assert exit_.value.code in (0, None)
    return root


def _replace(group: h5py.Group, name: str, **create) -> None:
    del group[name]
    group.create_dataset(name, **create)


BAD_CASES = {
    "nan_reamer_position": (lambda f: f["frames/reamer_position"].__setitem__((2, 0), np.nan), "reamer_position holds NaN"),
    "huge_peeq": (lambda f: _replace(f["frames"], "peeq", shape=(200_000, 12_000_000), dtype="f4", chunks=(1, 1024)), "GiB"),
    "string_tets": (lambda f: _replace(f["mesh"], "tets", data=np.array([[b"a", b"b", b"c", b"d"]])), "/mesh/tets has dtype"),
    "frames_a_dataset": (lambda f: (f.move("frames", "old"), f.create_dataset("frames", data=[1.0])), "/frames is a dataset"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_a_malformed_case_file_is_one_line(case, dataset, tmp_path, monkeypatch, capsys):
    spoil, needle = BAD_CASES[case]
    source = sorted((dataset / "cases").glob("*.h5"))[0]
    bad = tmp_path / "case.h5"
    shutil.copy(source, bad)
    with h5py.File(bad, "r+") as f:
        spoil(f)
    code, out, err = run_main(monkeypatch, capsys, "evaluate", "--data", str(bad), "--json")
    assert code == 2 and out == "" and "Traceback" not in err, (code, err)
    assert len(err.splitlines()) == 1 and needle in err, err


def test_a_pack_with_a_nan_reamer_position_is_refused_by_evaluate(dataset, tmp_path, monkeypatch, capsys):
    pack = tmp_path / "pack.h5"
    code, _, err = run_main(monkeypatch, capsys, "dataset", "pack", str(dataset), "--out", str(pack))
    assert code == 0, err
    with h5py.File(pack, "r+") as f:
        for case in f["cases"].values():  # whichever split evaluate reads
            case["reamer_position"][3, 2] = np.nan
    code, out, err = run_main(monkeypatch, capsys, "evaluate", "--data", str(pack), "--json")
    assert code == 2 and out == "" and "Traceback" not in err, (code, err)
    assert len(err.splitlines()) == 1 and "reamer_position holds NaN" in err, err


BAD_MANIFESTS = {
    "cases_a_list": (lambda m: m.update(cases=[1, 2]), "cases: Input should be a valid dictionary"),
    "entry_a_string": (lambda m: m["cases"].update({sorted(m["cases"])[0]: "x"}), "Input should be a valid dictionary"),
    "file_a_number": (lambda m: m["cases"][sorted(m["cases"])[0]].update(file=5), "file: Input should be a valid string"),
    "file_outside": (lambda m: m["cases"][sorted(m["cases"])[0]].update(file="../../elsewhere.h5"), "file: String should match"),
    "no_cases": (lambda m: m.pop("cases"), "cases: Field required"),
    "params_a_list": (lambda m: m["cases"][sorted(m["cases"])[0]].update(params=[1]), "params: Input should be a valid dictionary"),
}


@pytest.mark.parametrize("command", ["evaluate", "pack"])
@pytest.mark.parametrize("case", sorted(BAD_MANIFESTS))
def test_a_manifest_of_wrong_types_is_one_line(case, command, dataset, tmp_path, monkeypatch, capsys):
    spoil, needle = BAD_MANIFESTS[case]
    bad = tmp_path / "ds"
    shutil.copytree(dataset, bad)
    manifest = json.loads((bad / "manifest.json").read_text())
    spoil(manifest)
    (bad / "manifest.json").write_text(json.dumps(manifest))
    args = (
        ("evaluate", "--data", str(bad), "--json")
        if command == "evaluate"
        else ("dataset", "pack", str(bad), "--out", str(tmp_path / "p.h5"))
    )
    code, out, err = run_main(monkeypatch, capsys, *args)
    assert code == 2 and out == "" and "Traceback" not in err, (code, err)
    assert len(err.splitlines()) == 1 and "malformed dataset manifest" in err and needle in err, err
    assert not (tmp_path / "p.h5").exists()


def test_a_session_file_declaring_gigabytes_is_one_line(tmp_path, monkeypatch, capsys):
    session = tmp_path / "session.h5"
    with h5py.File(session, "w") as f:
        f.attrs.update({"format": "thrsim-session", "format_version": 1, "settings": json.dumps({"mode": "navigation"})})
        poses = f.create_group("inputs").create_group("poses")
        poses.create_dataset("matrix", shape=(80_000_000, 4, 4), dtype="f8", chunks=(64, 4, 4))
    assert session.stat().st_size < 100_000
    code, out, err = run_main(monkeypatch, capsys, "replay", str(session))
    assert code == 2 and out == "" and "Traceback" not in err, (code, err)
    assert len(err.splitlines()) == 1 and "/inputs/poses/matrix declares" in err and "GiB" in err, err
