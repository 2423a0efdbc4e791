"""The learning pack: a dataset reduced to what the learned simulator reads, in one small HDF5 file.

A case file keeps PEEQ and von Mises per element and frame (9–15 MB per case at the default
mesh). The learned simulator reads only the label α [7.2.1, eq. 47], which elements are removed,
and the reamer's path; a pack keeps exactly that for every complete case, with the mesh once, so
a trained model can ship the data it learned from and be re-trained and evaluated from a clone
without hours of solver runs (layout: :func:`write_pack`). α is stored in levels of 1/50, read
back at the level's centre (error ≤ 0.01, half the training noise; the removal threshold 0.3 is
a level boundary), damage in levels of 1/100 (0 and 1 exact): the levels make a pack small. The
labels' constants are fixed when the pack is made; reading it with other constants is refused.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from thrsim import __version__
from thrsim.atomic import atomic_path, hdf5_in_memory
from thrsim.config import LabelConfig
from thrsim.data.case_file import OPTIONAL_PER_ELEMENT, OPTIONAL_PER_FRAME, CaseReader, attr_value, data_digest, decode_attrs, file_sha256
from thrsim.data.labels import alpha as alpha_label
from thrsim.data.labels import compacting_elements
from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.mesh_io import read_mesh_group, write_mesh_group
from thrsim.hdf5_checks import group_at, read_dataset
from thrsim.provenance import config_hash, json_default, package_versions

PACK_FORMAT = "thrsim-learning-pack"
PACK_VERSION = 1  # every case on the pack's mesh
PACK_VERSION_OWN_MESHES = 2  # each case may carry its own mesh (the socket's windows and whole sockets)
ALPHA_LEVELS = 50
DAMAGE_LEVELS = 100
_SMALL_PER_FRAME = ("time", "reamer_position", "energy", *OPTIONAL_PER_FRAME)
SHARD_MB = 15.0
SHARD_NAME = "part-{:03d}.h5"
SHARD_GLOB = "part-*.h5"
_ALPHA_COMPRESSION = {"compression": "gzip", "compression_opts": 9, "shuffle": False}


@dataclass
class PackedCase:
    """One case read back from a pack."""

    case_id: str
    alpha: np.ndarray  # (T,E) float32, 0 for removed elements
    status: np.ndarray  # (T,E) uint8, 1 active 0 removed
    reamer_position: np.ndarray  # (T,3) m
    reamer_axis: np.ndarray  # (3,)
    split: str | None
    attrs: dict[str, Any]
    data_digest: str  # of the source case file (thrsim.data.case_file.data_digest)
    damage: np.ndarray | None = None  # (T,E) float32 D, where the case file records it
    damage_initiation: np.ndarray | None = None  # (T,E) float32 ω
    mesh: TetMesh | None = None  # the case's own mesh where it has one (a socket window), else None: the pack's
    contact_force_axial: np.ndarray | None = None  # (T,) N, where the case records it
    motor_torque: np.ndarray | None = None  # (T,) N·m, where the case records it


def pack_files(path: str | os.PathLike) -> list[Path]:
    """The files of a pack: the file itself, or a pack folder's ``part-*.h5`` in order."""
    path = Path(path)
    return sorted(path.glob(SHARD_GLOB)) if path.is_dir() else [path]


def is_pack(path: str | os.PathLike) -> bool:
    """True for a learning pack: an HDF5 file whose format attribute says so, or a folder of them."""
    files = pack_files(path)
    return bool(files) and all(_is_pack_file(f) for f in files)


def packed_case_ids(path: str | os.PathLike) -> tuple[str, frozenset[str]]:
    """The dataset identity hash and the case ids a learning pack (a file or a folder) holds."""
    files = pack_files(path)
    if not files or not all(f.is_file() and _is_pack_file(f) for f in files):
        raise ThrsimInputError(f"{path}: not a learning pack", "except_packed")
    hashes: set[str] = set()
    case_ids: set[str] = set()
    for file in files:
        with h5py.File(file, "r") as f:
            identity_hash = f.attrs.get("identity_hash", "")
            hashes.add(identity_hash.decode() if isinstance(identity_hash, bytes) else str(identity_hash))
            case_ids.update(f["cases"].keys() if "cases" in f else ())
    if len(hashes) != 1:
        raise ThrsimInputError(f"{path}: its files are packs of different datasets", "except_packed")
    return hashes.pop(), frozenset(case_ids)


def _is_pack_file(path: Path) -> bool:
    try:
        with h5py.File(path, "r") as f:
            value = f.attrs.get("format")
    except OSError:
        return False
    return value in (PACK_FORMAT, PACK_FORMAT.encode())


def quantise_alpha(alpha: np.ndarray) -> np.ndarray:
    """(T,E) α in [0, 1] → (E,T) uint8 levels (floor: a level never straddles a threshold k/50)."""
    return np.ascontiguousarray(np.floor(np.clip(np.asarray(alpha, dtype=np.float64), 0.0, 1.0) * ALPHA_LEVELS).astype(np.uint8).T)


def dequantise_alpha(levels: np.ndarray, alpha_levels: float = ALPHA_LEVELS) -> np.ndarray:
    """(E,T) uint8 levels → (T,E) float32 α at each level's centre (1 stays 1)."""
    return np.minimum((levels.T.astype(np.float32) + np.float32(0.5)) / np.float32(alpha_levels), np.float32(1.0))


def quantise_damage(damage: np.ndarray) -> np.ndarray:
    """(T,E) damage or initiation in [0, 1] → (E,T) uint8 levels, rounded (0 and 1 stay exact)."""
    return np.ascontiguousarray(np.rint(np.clip(np.asarray(damage, dtype=np.float64), 0.0, 1.0) * DAMAGE_LEVELS).astype(np.uint8).T)


def dequantise_damage(levels: np.ndarray, damage_levels: float = DAMAGE_LEVELS) -> np.ndarray:
    """(E,T) uint8 levels → (T,E) float32."""
    return levels.T.astype(np.float32) / np.float32(damage_levels)


def removal_frames(status: np.ndarray, where: str) -> np.ndarray:
    """(E,) int16: the first frame each element is removed in, −1 if never; refuses a revived element."""
    removed = np.asarray(status) == 0
    first = np.where(removed.any(axis=0), removed.argmax(axis=0), -1)
    frames = np.arange(len(removed))[:, None]
    rebuilt = (first[None, :] >= 0) & (frames >= first[None, :])
    if not np.array_equal(rebuilt, removed):
        raise ThrsimInputError(f"{where}: an element comes back after removal; a pack stores removal as one frame per element")
    return first.astype(np.int16)


def _status_from(first: np.ndarray, n_frames: int) -> np.ndarray:
    frames = np.arange(n_frames)[:, None]
    return np.where((first[None, :] >= 0) & (frames >= first[None, :]), 0, 1).astype(np.uint8)


def _json_attr(value: Any) -> str:
    return json.dumps(value, sort_keys=True, default=json_default)


def _pack_attrs(manifest: dict, labels: LabelConfig) -> dict[str, Any]:
    return {
        "format": PACK_FORMAT,
        "alpha_levels": ALPHA_LEVELS,
        "damage_levels": DAMAGE_LEVELS,
        "labels": _json_attr(labels.model_dump()),
        "identity": _json_attr(manifest["identity"]),
        "identity_hash": str(manifest.get("identity_hash") or config_hash(manifest["identity"])),
        "split_rule": _json_attr(manifest.get("split_rule")),
    }


def _write_case_group(group: h5py.Group, reader: CaseReader, entry: dict, labels: LabelConfig) -> None:
    """Reduce one case file into ``group``."""
    status = reader.series("status")
    if status is None:
        raise ThrsimInputError(f"{reader.path}: no /frames/status to pack")
    config = reader.attrs.get("config")
    alpha = alpha_label(
        reader.series("peeq"), reader.series("von_mises"), status, labels, damage=reader.series("damage"),
        compacting=compacting_elements(config, reader.mesh),
    )  # fmt: skip
    group.create_dataset("alpha", data=quantise_alpha(alpha), chunks=(min(4096, alpha.shape[1]), alpha.shape[0]), **_ALPHA_COMPRESSION)
    group.create_dataset("removed_frame", data=removal_frames(status, str(reader.path)), compression="gzip", compression_opts=9)
    for name in OPTIONAL_PER_ELEMENT:
        data = reader.series(name)
        if data is not None:
            group.create_dataset(name, data=quantise_damage(data), chunks=(min(4096, data.shape[1]), data.shape[0]), **_ALPHA_COMPRESSION)
    for name in _SMALL_PER_FRAME:
        data = reader.series(name)
        if data is not None:
            group.create_dataset(name, data=data)
    group["energy"].attrs["names"] = list(reader.energy_names)
    group.create_dataset("reamer_axis", data=reader.reamer_axis)
    attrs = {key: attr_value(value) for key, value in reader.attrs.items()}
    attrs.update(
        split=str(entry.get("split")),
        aliases=_json_attr(entry.get("params", {}).get("aliases")),
        source_file=str(entry.get("file", reader.path.name)),
        source_sha256=file_sha256(reader.path),
        source_data_digest=entry.get("data_digest") or data_digest(reader.path),
        wall_s=float("nan") if entry.get("wall_s") is None else float(entry["wall_s"]),  # None: a file adopted, not timed
    )
    group.attrs.update(attrs)


def _socket_pack(attrs: dict[str, Any]) -> bool:
    """Whether the pack is of the socket (windows and whole sockets), each case on its own mesh."""
    return json.loads(attrs["identity"]).get("template", {}).get("bone_kind") == "socket"


def _same_mesh(a: TetMesh, b: TetMesh) -> bool:
    return (
        a.nodes.shape == b.nodes.shape
        and a.tets.shape == b.tets.shape
        and np.array_equal(a.nodes, b.nodes)
        and np.array_equal(a.tets, b.tets)
    )


def _check_same_source(existing: h5py.File, attrs: dict[str, Any], out: Path) -> None:
    for key in ("identity_hash", "labels", "alpha_levels"):
        have = existing.attrs.get(key)
        have = have.decode() if isinstance(have, bytes) else have
        if have != attrs[key]:
            raise ThrsimInputError(f"{out} is an existing pack of another dataset or format ({key} differs); give another", "out")


def write_pack(
    dataset_dir: str | os.PathLike, out: str | os.PathLike, labels: LabelConfig | None = None, shard_mb: float = SHARD_MB
) -> dict[str, Any]:
    """Pack every complete case of ``dataset_dir`` into ``out``, keeping the cases ``out`` already holds.

    ``out`` ending in ``.h5`` is one file; otherwise a folder of pack files (``part-000.h5``, …),
    each a whole pack of some of the cases, a new one begun when the last would pass ``shard_mb``
    megabytes (git hosts refuse or warn about single files over 20–100 MB).

    Adding to an existing pack is how a sweep spread over several machines or sessions is
    gathered: the pack must come from the same dataset identity, labels and mesh, and a case
    present in both must have the same data digest. Each file is written to a temporary name
    and renamed.

    Layout::

        attrs   format="thrsim-learning-pack", version, alpha_levels, damage_levels, labels (JSON LabelConfig),
                identity (JSON, the dataset's), identity_hash, split_rule (JSON), thrsim_version,
                versions (JSON), updated
        /mesh                      the case files' mesh group (the first case's, in a pack of socket windows)
        /cases/<case_id>           attrs: the case file's attributes, split, aliases, source_file,
                                   source_sha256, source_data_digest, wall_s
            alpha     (E,T) uint8  floor(α·alpha_levels) of active elements, one element's history
                                   per row (the far field is nearly constant in time, so rows
                                   compress well)
            removed_frame (E,) int16   first frame the element is removed in (STATUS = 0), −1 never
            damage, damage_initiation (E,T) uint8   round(D·damage_levels), round(ω·damage_levels),
                                   where the case file records them (thrsim ≥ 0.3.1)
            time, reamer_position, reamer_axis, energy (+ names) and the optional per-frame series,
                                   as in the case file
            mesh                   the case's own mesh group where it is not the pack's (version 2: the
                                   socket's windows and whole sockets; compressed, one copy per file
                                   of each mesh, hard-linked from every case on it); version 1 packs
                                   hold one mesh
    """
    from thrsim.data.generate import load_dataset, read_manifest

    labels = labels or LabelConfig()
    root, out = Path(dataset_dir), Path(out)
    manifest = read_manifest(root)
    if manifest is None:
        raise ThrsimInputError(f"{root}: not a thrsim dataset (no manifest.json)")
    entries = load_dataset(root)
    attrs = _pack_attrs(manifest, labels)
    if out.suffix == ".h5":
        if not entries and not out.exists():
            raise ThrsimInputError(f"{root}: no complete case to pack")
        kept, added = _write_pack_file(out, entries, attrs, labels)
        return {"pack": str(out), "cases": len(kept) + len(added), "added": sorted(added), "kept": len(kept), "bytes": out.stat().st_size}
    if out.exists() and not out.is_dir():
        raise ThrsimInputError(f"{out}: exists and is not a folder (a one-file pack is named *.h5)")
    if not out.parent.is_dir():
        raise ThrsimInputError(f"{out}: parent folder {out.parent} does not exist")
    shards = pack_files(out) if out.is_dir() else []
    held: dict[str, str] = {}
    for shard in shards:
        if not _is_pack_file(shard):
            raise ThrsimInputError(f"{shard} is not a learning pack; give another", "out")
        with h5py.File(shard, "r") as existing:
            _check_same_source(existing, attrs, shard)
            held.update({case_id: existing["cases"][case_id].attrs["source_data_digest"] for case_id in existing["cases"]})
    if not entries and not held:
        raise ThrsimInputError(f"{root}: no complete case to pack")
    out.mkdir(exist_ok=True)
    limit = shard_mb * 1e6
    added = []
    for entry in entries:
        if entry["case_id"] in held:
            if held[entry["case_id"]] != (entry.get("data_digest") or data_digest(entry["path"])):
                raise ThrsimInputError(f"{out}: case {entry['case_id']} is packed from other data than {entry['path']}")
            continue
        target = shards[-1] if shards and shards[-1].stat().st_size + _estimated_bytes(shards[-1], entry) <= limit else None
        if target is None:
            target = out / SHARD_NAME.format(len(shards))
            shards.append(target)
        _write_pack_file(target, [entry], attrs, labels)
        added.append(entry["case_id"])
    return {
        "pack": str(out),
        "files": [p.name for p in shards],
        "cases": len(held) + len(added),
        "added": sorted(added),
        "kept": len(held),
        "bytes": sum(p.stat().st_size for p in shards),
    }


def _estimated_bytes(shard: Path, entry: dict) -> float:
    """A case's packed size, from the shard's bytes per element and frame (its mesh included: an
    overestimate; a whole socket has seven times a window's elements)."""
    with h5py.File(shard, "r") as f:
        element_frames = sum(f["cases"][case_id]["alpha"].size for case_id in f["cases"])
    with CaseReader(entry["path"]) as reader:
        case_element_frames = reader.n_frames * reader.n_elements
    return shard.stat().st_size / max(element_frames, 1) * case_element_frames


class _OwnMeshes:
    """The cases' own meshes of one pack file, each stored once, compressed: a case on a mesh
    already stored links to it (an HDF5 hard link; the whole sockets of one size share one)."""

    def __init__(self) -> None:
        self.stored: list[tuple[TetMesh, h5py.Group]] = []

    def place(self, case: h5py.Group, mesh: TetMesh) -> None:
        for known, group in self.stored:
            if _same_mesh(known, mesh):
                case["mesh"] = group
                return
        self.stored.append((mesh, case.create_group("mesh")))
        write_mesh_group(self.stored[-1][1], mesh, compress=True)


def _write_pack_file(out: Path, entries: list[dict], attrs: dict[str, Any], labels: LabelConfig) -> tuple[list[str], list[str]]:
    """One pack file: the cases ``out`` holds (checked to be of the same source) plus ``entries``; (kept, added).
    In a pack of the socket every case has its own mesh, and ``/mesh`` links to the first."""
    kept, added = [], []
    socket = _socket_pack(attrs)
    own_meshes = _OwnMeshes()
    with atomic_path(out, suffix=".tmp") as tmp, hdf5_in_memory(tmp) as f:
        cases = f.create_group("cases")
        mesh = None
        if out.exists():
            if not _is_pack_file(out):
                raise ThrsimInputError(f"{out} exists and is not a learning pack; give another", "out")
            with h5py.File(out, "r") as existing:
                mesh = read_mesh_group(existing["mesh"])
                _check_same_source(existing, attrs, out)
                for case_id, source in existing["cases"].items():
                    group = cases.create_group(case_id)
                    group.attrs.update(source.attrs)
                    for name in source:
                        if name != "mesh":
                            existing.copy(source[name], group, name=name)
                    if socket:
                        own_meshes.place(group, read_mesh_group(source["mesh"]) if "mesh" in source else mesh)
                    kept.append(case_id)
        for entry in entries:
            with CaseReader(entry["path"]) as reader:
                if entry["case_id"] in cases:
                    if cases[entry["case_id"]].attrs["source_data_digest"] != (entry.get("data_digest") or data_digest(reader.path)):
                        raise ThrsimInputError(f"{out}: case {entry['case_id']} is packed from other data than {reader.path}")
                    continue
                group = cases.create_group(entry["case_id"])
                if socket:
                    own_meshes.place(group, reader.mesh)  # a window or a whole socket: its own mesh
                elif mesh is not None and not _same_mesh(mesh, reader.mesh):
                    del cases[entry["case_id"]]
                    raise ThrsimInputError(f"{reader.path}: its mesh differs from the pack's (a pack of the patch holds one mesh)")
                if mesh is None:
                    mesh = reader.mesh
                _write_case_group(group, reader, entry, labels)
                added.append(entry["case_id"])
        if mesh is None:
            raise ThrsimInputError(f"{out}: no case to pack")
        if socket:
            f["mesh"] = own_meshes.stored[0][1]
        else:
            write_mesh_group(f.create_group("mesh"), mesh)
        f.attrs.update(
            {
                **attrs,
                "version": PACK_VERSION_OWN_MESHES if socket else PACK_VERSION,
                "thrsim_version": __version__,
                "versions": _json_attr(package_versions()),
                "updated": datetime.now(UTC).isoformat(timespec="seconds"),
            }
        )
    return kept, added


def read_pack(
    path: str | os.PathLike, splits: tuple[str, ...] | None = None, labels: LabelConfig | None = None
) -> tuple[TetMesh, list[PackedCase]]:
    """The mesh and the cases (optionally some splits only) of a learning pack (one file or a folder of them)."""
    path = Path(path)
    if not is_pack(path):
        raise ThrsimInputError(f"{path}: not a thrsim learning pack")
    mesh, out, first = None, {}, None
    for shard in pack_files(path):
        with h5py.File(shard, "r") as f:
            source = {key: f.attrs.get(key) for key in ("identity_hash", "labels", "alpha_levels")}
            if first is None:
                first = source
            elif source != first:
                raise ThrsimInputError(f"{shard}: packed from another dataset or with other constants than {pack_files(path)[0].name}")
            shard_mesh, cases = _read_pack_file(shard, f, splits, labels)
        if mesh is None:
            mesh = shard_mesh
        elif cases and not _same_mesh(mesh, shard_mesh) and not any(case.mesh is not None for case in cases):
            raise ThrsimInputError(f"{shard}: its mesh differs from the other pack files'")
        for case in cases:
            if case.case_id in out:
                raise ThrsimInputError(f"{path}: case {case.case_id} is in two pack files")
            out[case.case_id] = case
    if mesh is None:
        raise ThrsimInputError(f"{path}: a learning pack without a pack file")
    return mesh, [out[case_id] for case_id in sorted(out)]


def _read_pack_file(
    path: Path, f: h5py.File, splits: tuple[str, ...] | None, labels: LabelConfig | None
) -> tuple[TetMesh, list[PackedCase]]:
    try:
        version = int(f.attrs.get("version", -1))
        packed_labels = LabelConfig.model_validate_json(f.attrs["labels"]).model_dump()
        labels_know_crushed_bone = "crushed_bone_is_lost" in json.loads(f.attrs["labels"])
        levels, damage_levels = (
            float(f.attrs.get(key, default)) for key, default in (("alpha_levels", None), ("damage_levels", DAMAGE_LEVELS))
        )
    except (KeyError, TypeError, ValueError) as error:  # pydantic's ValidationError is a ValueError
        raise ThrsimInputError(
            f"{path}: the pack's version, label constants or levels are missing or malformed ({str(error).splitlines()[0]})"
        ) from None
    if version not in (PACK_VERSION, PACK_VERSION_OWN_MESHES):
        raise ThrsimInputError(
            f"{path}: learning pack version {version}; this thrsim reads versions {PACK_VERSION} and {PACK_VERSION_OWN_MESHES}"
        )
    if not (1 <= levels <= 255 and 1 <= damage_levels <= 255):
        raise ThrsimInputError(f"{path}: the pack's levels ({levels:g}, {damage_levels:g}) do not fit its uint8 values")
    if labels is not None and labels.model_dump() != packed_labels:
        raise ThrsimInputError(f"{path}: packed with label constants {packed_labels}; α cannot be recomputed with others from a pack")
    mesh = read_mesh_group(group_at(f, "mesh", path))
    cases = group_at(f, "cases", path)
    out = []
    for case_id in sorted(cases):
        g = group_at(cases, case_id, path)
        attrs = decode_attrs(g.attrs)
        split = attrs.pop("split", None)
        split = None if split in (None, "None") else split
        if splits is not None and split not in splits:
            continue
        own_mesh = None
        if version == PACK_VERSION_OWN_MESHES:  # each case its mesh: its own, or its file's (files of a pack differ)
            own_mesh = read_mesh_group(group_at(g, "mesh", path)) if "mesh" in g else mesh
        elements = (own_mesh or mesh).n_tets
        config = attrs.get("config")
        if not labels_know_crushed_bone and compacting_elements(config, own_mesh or mesh).any():
            raise ThrsimInputError(
                f"{path}: case {case_id}'s cancellous bone compacts, and the pack was made before its labels kept crushed bone: "
                "pack its dataset again"
            )
        quantised = read_dataset(g, "alpha", path, "u", (elements, None))
        frames = quantised.shape[1]
        status = _status_from(read_dataset(g, "removed_frame", path, "iu", (elements,)), frames)
        alpha = np.where(status == 1, dequantise_alpha(quantised, levels), np.float32(0.0))
        out.append(PackedCase(
            case_id=case_id,
            alpha=alpha.astype(np.float32),
            status=status,
            reamer_position=read_dataset(g, "reamer_position", path, "f", (frames, 3)),
            reamer_axis=read_dataset(g, "reamer_axis", path, "f", (3,)),
            split=split,
            attrs=attrs,
            data_digest=str(attrs.get("source_data_digest", "")),
            mesh=own_mesh,
            contact_force_axial=read_dataset(g, "contact_force_axial", path, "f", (frames,)) if "contact_force_axial" in g else None,
            motor_torque=read_dataset(g, "motor_torque", path, "f", (frames,)) if "motor_torque" in g else None,
            **{
                name: dequantise_damage(read_dataset(g, name, path, "u", (elements, frames)), damage_levels) if name in g else None
                for name in OPTIONAL_PER_ELEMENT
            },
        ))  # fmt: skip
    return mesh, out
