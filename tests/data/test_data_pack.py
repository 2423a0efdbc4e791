"""`thrsim dataset pack`: a dataset reduced to α, removals and the reamer path, read back by the learner."""

from __future__ import annotations

import json
import shutil
import sys

import h5py
import numpy as np
import pytest
from checkout_cli import run_main

from thrsim.cli import main
from thrsim.config import LabelConfig
from thrsim.data.case_file import read_case
from thrsim.data.generate import load_dataset, read_manifest, write_manifest
from thrsim.data.pack import (
    ALPHA_LEVELS,
    DAMAGE_LEVELS,
    dequantise_alpha,
    dequantise_damage,
    is_pack,
    pack_files,
    quantise_alpha,
    quantise_damage,
    read_pack,
    removal_frames,
    write_pack,
)
from thrsim.errors import ThrsimInputError
from thrsim.learn.cases import load_cases

pytestmark = pytest.mark.timeout(180)

SWEEP = [
    "--inclinations",
    "0,15,30",
    "--anteversions",
    "0,45,90",
    "--frames",
    "8",
    "--extra-forces",
    "none",
    "--solver",
    "synthetic",
    "--element-sizes",
    "1.0",
]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("pack") / "ds"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sys, "argv", ["thrsim", "dataset", "--out", str(root), *SWEEP, "--json"])
        with pytest.raises(SystemExit) as exit_:
            main()
    assert exit_.value.code in (0, None)
    return root


def test_a_pack_reads_back_as_the_dataset_does(dataset, tmp_path, monkeypatch, capsys):
    pack = tmp_path / "learning.h5"
    code, out, err = run_main(monkeypatch, capsys, "dataset", "pack", str(dataset), "--out", str(pack), "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["cases"] == 7 and summary["kept"] == 0 and len(summary["added"]) == 7
    mesh_dir, from_dir = load_cases(dataset)
    mesh_pack, from_pack = load_cases(pack)
    assert np.array_equal(mesh_dir.tets, mesh_pack.tets) and np.array_equal(mesh_dir.nodes, mesh_pack.nodes)
    assert [c.case_id for c in from_dir] == [c.case_id for c in from_pack]
    changed = 0
    for full, packed in zip(from_dir, from_pack, strict=True):
        assert (packed.split, packed.digest, packed.force_n, packed.end_reason) == (full.split, full.digest, full.force_n, full.end_reason)
        assert np.array_equal(packed.positions, full.positions) and np.array_equal(packed.axis, full.axis)
        assert np.abs(packed.alpha - full.alpha).max() <= 0.5 / ALPHA_LEVELS + 1e-6
        assert np.array_equal(packed.alpha < 0.3, full.alpha < 0.3)  # the removal rule sees the same elements
        changed += int(np.any(np.diff(full.alpha < 0.3, axis=0)))
    assert changed >= 3  # the sweep removes elements: the comparison above is not of constant arrays
    _, test_only = load_cases(pack, splits=("test",))
    assert {c.split for c in test_only} == {"test"} and len(test_only) == 2


def _same_cases(a, b) -> bool:
    return [c.case_id for c in a] == [c.case_id for c in b] and all(
        np.array_equal(x.alpha, y.alpha)
        and np.array_equal(x.status, y.status)
        and np.array_equal(x.damage, y.damage)
        and x.split == y.split
        for x, y in zip(a, b, strict=True)
    )


def test_a_pack_folder_splits_the_cases_into_files_and_reads_back_as_one(dataset, tmp_path, monkeypatch, capsys):
    single = tmp_path / "one.h5"
    write_pack(dataset, single)
    limit_mb = single.stat().st_size / 3 / 1e6  # about three files
    partial = tmp_path / "partial"  # a sweep gathered in two goes: four cases, then all seven
    shutil.copytree(dataset, partial)
    manifest = read_manifest(partial)
    later = sorted(manifest["cases"])[4:]
    for case_id in later:
        manifest["cases"][case_id]["status"] = "pending"
    write_manifest(partial, manifest)
    folder = tmp_path / "pack"
    first = write_pack(partial, folder, shard_mb=limit_mb)
    assert first["cases"] == 4 and first["kept"] == 0
    code, out, err = run_main(monkeypatch, capsys, "dataset", "pack", str(dataset), "--out", str(folder), "--shard-mb", "1", "--json")
    assert code == 0, err  # the CLI's least limit holds all here: the rest joins the last file
    summary = write_pack(dataset, tmp_path / "pack-small", shard_mb=limit_mb)
    files = pack_files(tmp_path / "pack-small")
    assert summary["cases"] == 7 and len(files) >= 3 and [p.name for p in files] == summary["files"]
    assert all(p.stat().st_size <= 1.5 * limit_mb * 1e6 for p in files)  # a file closes near the limit
    assert is_pack(tmp_path / "pack-small") and not is_pack(dataset) and not is_pack(tmp_path / "nowhere")
    merged = json.loads(out)
    assert merged["cases"] == 7 and merged["kept"] == 4 and sorted(merged["added"]) == later
    _, from_single = read_pack(single)
    for packed in (folder, tmp_path / "pack-small"):
        _, from_folder = read_pack(packed)
        assert _same_cases(from_single, from_folder)
        _, test_only = load_cases(packed, splits=("test",))
        assert {c.split for c in test_only} == {"test"} and len(test_only) == 2
    again = write_pack(dataset, tmp_path / "pack-small", shard_mb=limit_mb)
    assert again["added"] == [] and again["kept"] == 7 and pack_files(tmp_path / "pack-small") == files
    # a case in two files, or a file from another pack, is refused in one line
    shutil.copy(files[0], tmp_path / "pack-small" / "part-999.h5")
    with pytest.raises(ThrsimInputError, match="in two pack files"):
        read_pack(tmp_path / "pack-small")
    (tmp_path / "pack-small" / "part-999.h5").unlink()
    with h5py.File(files[-1], "r+") as f:
        f.attrs["identity_hash"] = "another"
    with pytest.raises(ThrsimInputError, match="another dataset"):
        read_pack(tmp_path / "pack-small")
    code, _, err = run_main(monkeypatch, capsys, "dataset", "pack", str(dataset), "--out", str(single / "x"))
    assert code != 0 and err.count("\n") == 1


def test_a_socket_pack_stores_each_mesh_once_and_reads_back_a_file_of_one_case(dataset, tmp_path):
    socket = tmp_path / "socket"  # the same cases packed as the socket's: each case carries its mesh
    shutil.copytree(dataset, socket)
    manifest = read_manifest(socket)
    manifest["identity"]["template"]["bone_kind"] = "socket"
    write_manifest(socket, manifest)
    one = tmp_path / "one.h5"
    write_pack(socket, one)
    with h5py.File(one, "r") as f:
        meshes = [group["mesh"] for group in f["cases"].values()]
        assert len(meshes) == 7 and all(mesh == f["mesh"] for mesh in meshes)  # one stored copy, linked from each case
        assert f["mesh/tets"].compression == "gzip" and f.attrs["version"] == 2
    plain = tmp_path / "plain.h5"
    write_pack(dataset, plain)
    folder = tmp_path / "pack"
    summary = write_pack(socket, folder, shard_mb=1e-3)  # below one case: a file for each
    assert len(summary["files"]) == 7
    _, from_files = read_pack(folder)
    _, from_one = read_pack(one)
    _, from_plain = read_pack(plain)
    assert _same_cases(from_files, from_one) and _same_cases(from_one, from_plain)
    assert all(case.mesh is not None and case.mesh.n_tets == case.alpha.shape[1] for case in from_files)
    write_pack(socket, one)  # kept cases keep their shared mesh when the file is written again
    with h5py.File(one, "r") as f:
        assert all(group["mesh"] == f["mesh"] for group in f["cases"].values())


def test_a_pack_keeps_each_elements_damage_to_a_hundredth(dataset, tmp_path, monkeypatch, capsys):
    pack = tmp_path / "learning.h5"
    assert run_main(monkeypatch, capsys, "dataset", "pack", str(dataset), "--out", str(pack))[0] == 0
    _, packed = read_pack(pack)
    paths = {entry["case_id"]: entry["path"] for entry in load_dataset(dataset)}
    damaged = 0
    for case in packed:
        frames = read_case(paths[case.case_id]).frames
        for name in ("damage", "damage_initiation"):
            assert np.abs(getattr(case, name) - getattr(frames, name)).max() <= 0.5 / DAMAGE_LEVELS + 1e-6
        assert np.all(case.damage[frames.damage == 0] == 0) and np.all(
            case.damage[frames.damage == 1] == 1
        )  # undamaged and deleted stay exact
        damaged += int((frames.damage > 0).sum())
    assert damaged > 0  # the sweep damages elements: the comparison above is not of zeros


def test_damage_levels_keep_zero_and_one_exact():
    damage = np.array([[0.0, 0.004, 0.006, 0.5, 0.996, 1.0]], dtype=np.float32)
    back = dequantise_damage(quantise_damage(damage))
    assert back[0, 0] == 0.0 and back[0, -1] == 1.0 and back[0, 1] == 0.0 and back[0, -2] == 1.0
    assert np.abs(back - damage).max() <= 0.5 / DAMAGE_LEVELS + 1e-6


def test_packs_gather_a_sweep_run_in_parts(dataset, tmp_path, monkeypatch, capsys):
    part = tmp_path / "part"
    shutil.copytree(dataset, part)
    manifest = read_manifest(part)
    held_back = sorted(manifest["cases"])[-3:]
    for case_id in held_back:
        manifest["cases"][case_id]["status"] = "pending"
    write_manifest(part, manifest)
    pack = tmp_path / "learning.h5"
    code, out, err = run_main(monkeypatch, capsys, "dataset", "pack", str(part), "--out", str(pack), "--json")
    assert code == 0 and json.loads(out)["cases"] == 4, err
    code, out, err = run_main(monkeypatch, capsys, "dataset", "pack", str(dataset), "--out", str(pack), "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["kept"] == 4 and summary["added"] == held_back and summary["cases"] == 7

    before = pack.read_bytes()
    other_frames = tmp_path / "other-frames"  # another identity: the frame count is part of it
    code, _, err = run_main(monkeypatch, capsys, "dataset", "--out", str(other_frames), *SWEEP[:4], "--frames", "6", *SWEEP[6:], "--json")
    assert code == 0, err
    code, out, err = run_main(monkeypatch, capsys, "dataset", "pack", str(other_frames), "--out", str(pack))
    assert code != 0 and "another dataset" in err and err.count("\n") == 1
    other_mesh = tmp_path / "other-mesh"  # per-case element sizes stay out of the identity: the mesh check refuses
    code, _, err = run_main(
        monkeypatch,
        capsys,
        "dataset",
        "--out",
        str(other_mesh),
        *SWEEP[:-2],
        "--element-sizes",
        "2.0",
        "--inclinations",
        "0",
        "--anteversions",
        "0",
        "--json",
    )
    assert code == 0, err
    code, out, err = run_main(monkeypatch, capsys, "dataset", "pack", str(other_mesh), "--out", str(pack))
    assert code != 0 and "mesh differs" in err and err.count("\n") == 1
    assert pack.read_bytes() == before  # a refused merge leaves the pack as it was


def test_a_sweep_solved_on_two_machines_skips_what_the_pack_holds(dataset, tmp_path, monkeypatch, capsys):
    pack = tmp_path / "pack"
    first = tmp_path / "first-machine"
    code, _, err = run_main(monkeypatch, capsys, "dataset", "--out", str(first), *SWEEP[2:], "--inclinations", "0,15", "--json")
    assert code == 0, err
    code, out, err = run_main(monkeypatch, capsys, "dataset", "pack", str(first), "--out", str(pack), "--json")
    assert code == 0 and json.loads(out)["cases"] == 4, err

    second = tmp_path / "second-machine"
    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(second), *SWEEP, "--except-packed", str(pack), "--json")
    assert code == 0, err
    assert json.loads(out)["cases"] == 3 and sorted(read_manifest(second)["cases"]) == sorted(
        set(read_manifest(dataset)["cases"]) - set(read_manifest(first)["cases"])
    )
    code, out, err = run_main(monkeypatch, capsys, "dataset", "pack", str(second), "--out", str(pack), "--json")
    assert code == 0 and json.loads(out)["cases"] == 7, err
    whole = tmp_path / "whole.h5"
    assert run_main(monkeypatch, capsys, "dataset", "pack", str(dataset), "--out", str(whole))[0] == 0
    assert _same_cases(read_pack(pack)[1], read_pack(whole)[1])  # as if one machine had solved it all

    code, out, err = run_main(monkeypatch, capsys, "dataset", "--out", str(tmp_path / "third"), *SWEEP, "--except-packed", str(pack))
    assert code == 0 and "nothing to run" in err and not (tmp_path / "third").exists()
    other = tmp_path / "other-frames"  # another identity: the frame count is part of it
    args = [*SWEEP[:4], "--frames", "6", *SWEEP[6:], "--except-packed", str(pack)]
    code, _, err = run_main(monkeypatch, capsys, "dataset", "--out", str(other), *args)
    assert code == 2 and "a pack of another dataset" in err and err.count("\n") == 1 and not other.exists()
    code, _, err = run_main(monkeypatch, capsys, "dataset", "--out", str(other), *SWEEP, "--except-packed", str(dataset / "manifest.json"))
    assert code == 2 and "not a learning pack" in err and err.count("\n") == 1 and not other.exists()


def test_bad_targets_and_sources_get_one_line(dataset, tmp_path, monkeypatch, capsys):
    code, _, err = run_main(monkeypatch, capsys, "dataset", "pack", str(tmp_path / "nothing"), "--out", str(tmp_path / "p.h5"))
    assert code != 0 and "not a thrsim dataset" in err and err.count("\n") == 1
    code, _, err = run_main(monkeypatch, capsys, "dataset", "pack", str(dataset), "--out", str(dataset / "manifest.json"))
    assert code != 0 and "is not a folder" in err and err.count("\n") == 1  # not *.h5: a pack folder
    not_a_pack = tmp_path / "other.h5"
    not_a_pack.write_bytes(b"not hdf5")
    code, _, err = run_main(monkeypatch, capsys, "dataset", "pack", str(dataset), "--out", str(not_a_pack))
    assert code != 0 and "not a learning pack" in err and err.count("\n") == 1 and not_a_pack.read_bytes() == b"not hdf5"
    assert json.loads((dataset / "manifest.json").read_text())["format"] == "thrsim-dataset"
    pack = tmp_path / "p.h5"
    code, _, err = run_main(monkeypatch, capsys, "dataset", "pack", str(dataset), "--out", str(pack))
    assert code == 0, err
    with pytest.raises(ThrsimInputError, match="label constants"):
        read_pack(pack, labels=LabelConfig(mu=0.5))
    with h5py.File(pack, "r+") as f:
        f.attrs["version"] = 99
    with pytest.raises(ThrsimInputError, match="version 99"):
        load_cases(pack)


def test_quantisation_keeps_every_element_on_its_side_of_the_threshold():
    rng = np.random.default_rng(3)
    levels = np.arange(ALPHA_LEVELS + 1) / ALPHA_LEVELS
    alpha = (
        np.concatenate([rng.random(5000), levels, np.nextafter(levels, -1), np.nextafter(levels, 2)]).clip(0, 1).astype(np.float32)[None, :]
    )
    back = dequantise_alpha(quantise_alpha(alpha))
    assert np.abs(back - alpha).max() <= 0.5 / ALPHA_LEVELS + 1e-6
    for threshold in (0.3, 0.5, 0.1):
        assert np.array_equal(back < threshold, alpha < threshold)


def test_removal_is_one_frame_per_element_and_revival_is_refused():
    status = np.array([[1, 1, 1], [1, 0, 1], [0, 0, 1]], dtype=np.uint8)
    assert removal_frames(status, "x").tolist() == [2, 1, -1]
    with pytest.raises(ThrsimInputError, match="comes back"):
        removal_frames(np.array([[1], [0], [1]], dtype=np.uint8), "x")


@pytest.mark.timeout(900)  # a whole socket solved for two frames, on a coarse mesh
def test_a_socket_s_crushed_cancellous_bone_is_packed_as_bone_and_an_older_pack_of_it_is_refused(tmp_path, monkeypatch, capsys):
    """The rim's crush compacts the cancellous bone behind it; the pack's labels keep it, and a pack
    whose label constants predate that (eq. 47 reading compaction as loss) is refused, not misread."""
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({
        "train_cases": 0, "validation_cases": 0, "test_cases": 0, "pushed_windows": [], "test_pushed_windows": [],
        "whole_sockets": [[46, 48, 0, 0, 230, "train"]], "prepared_whole_sockets": [], "long_whole_sockets": [],
        "whole_socket_element_sizes_mm": [2.5],
    }))  # fmt: skip
    root, pack = tmp_path / "ds", tmp_path / "pack.h5"
    args = ["dataset", "--bone", "socket", "--socket-plan", str(plan), "--frames", "2", "--out", str(root), "--threads", "1"]
    code, _, err = run_main(monkeypatch, capsys, *args)
    assert code == 0, err
    write_pack(root, pack)
    (case_file,) = (root / "cases").glob("*.h5")
    with h5py.File(case_file, "r") as f:
        cancellous, kept = f["mesh/material"][()] == 1, f["frames/status"][-1] == 1
        crushed = cancellous & kept & (f["frames/peeq"][-1] > 0.42)
    _, (case,) = load_cases(pack, one_mesh=False)
    assert crushed.any() and not (case.alpha[-1] < 0.3)[crushed].any()
    with h5py.File(pack, "r+") as f:  # as a pack made before the labels kept crushed bone
        labels = json.loads(f.attrs["labels"])
        del labels["crushed_bone_is_lost"]
        f.attrs["labels"] = json.dumps(labels)
    with pytest.raises(ThrsimInputError, match="pack its dataset again"):
        read_pack(pack)
