"""The ground-truth case file: one HDF5 file per reaming case.

Attributes (the case's orientation, force, spin, frame time, configuration and its hash, the
versions, frame and element counts, how it ended), the mesh (``/mesh``: nodes in m, tets, fixed
nodes, node sets, materials) and per frame (``/frames``: time, each element's status, PEEQ, von
Mises stress, damage and its initiation, the reamer's position and axial motion, energies,
contact, reaction and push forces, motor torque); the full layout, with units and the versions
that added each dataset, is the docs' Data formats page (case file). Per-element datasets are
chunked one frame per chunk and gzip-compressed (level 1), so a reader streams frames without
loading the whole case. Frame 0 is the intact bone before contact. Files are written to a
temporary name in the target folder, fsynced and renamed: a reader never sees a half-written case.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from thrsim import __version__
from thrsim.atomic import atomic_path, hdf5_in_memory
from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.mesh_io import read_mesh_group, write_mesh_group
from thrsim.hdf5_checks import check_dataset, dataset_at, group_at, read_dataset
from thrsim.provenance import config_hash, json_default, package_versions

CASE_FORMAT = "thrsim-case"
CASE_VERSION = 1
REQUIRED_ENERGIES = ("kinetic", "internal")
PER_ELEMENT = ("status", "peeq", "von_mises")
#: per-element datasets a case may carry (older solvers did not record them)
OPTIONAL_PER_ELEMENT = ("damage", "damage_initiation")
#: per-frame datasets a case may carry (older solvers wrote fewer), with their trailing shape
OPTIONAL_PER_FRAME = {
    "contact_force": (3,),
    "reamer_axial": (3,),
    "contact_force_axial": (),
    "contact_fraction": (),
    "reaction_force": (3,),
    "motor_torque": (),
    "push_force": (),
}
_COMPRESSION = {"compression": "gzip", "compression_opts": 1, "shuffle": True}
#: the small per-frame datasets a reader takes whole, with their trailing shape
_PER_FRAME_SHAPES = {"reamer_position": (3,), **OPTIONAL_PER_FRAME}


@dataclass
class CaseFrames:
    """Everything recorded per output frame."""

    time: np.ndarray  # (T,) s
    status: np.ndarray  # (T,E) uint8 1 active 0 removed
    peeq: np.ndarray  # (T,E) float32
    von_mises: np.ndarray  # (T,E) float32 Pa
    reamer_position: np.ndarray  # (T,3) float64 m
    energy: np.ndarray  # (T,k) float64 J
    energy_names: tuple[str, ...]  # at least "kinetic" and "internal"
    contact_force: np.ndarray | None = None  # (T,3) N
    reamer_axial: np.ndarray | None = None  # (T,3) m: within-frame mean, min, max of s
    contact_force_axial: np.ndarray | None = None  # (T,) N
    reaction_force: np.ndarray | None = None  # (T,3) N on the reamer
    motor_torque: np.ndarray | None = None  # (T,) N·m about D
    push_force: np.ndarray | None = None  # (T,) N along D: the set push, or what a prescribed feed takes
    contact_fraction: np.ndarray | None = None  # (T,)
    damage: np.ndarray | None = None  # (T,E) float32
    damage_initiation: np.ndarray | None = None  # (T,E) float32

    @property
    def n_frames(self) -> int:
        return int(len(self.time))

    @property
    def n_elements(self) -> int:
        return int(np.shape(self.status)[1])


@dataclass
class Case:
    """A case read back: the mesh, the frames and the file's attributes (JSON attrs decoded)."""

    path: Path
    mesh: TetMesh
    frames: CaseFrames
    reamer_axis: np.ndarray
    attrs: dict[str, Any] = field(default_factory=dict)


def attr_value(value: Any) -> Any:
    """HDF5 attrs take scalars and strings; anything else is stored as JSON text."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, float, str, np.integer, np.floating)):
        return value
    if value is None:
        return "null"
    return json.dumps(value, default=json_default)


def _check_frames(frames: CaseFrames, mesh: TetMesh, where: str) -> None:
    t = frames.n_frames
    e = mesh.n_tets
    expected = {
        "time": (t,),
        "status": (t, e),
        "peeq": (t, e),
        "von_mises": (t, e),
        "reamer_position": (t, 3),
    }
    expected.update({name: (t, e) for name in OPTIONAL_PER_ELEMENT if getattr(frames, name) is not None})
    for name, shape in expected.items():
        got = np.shape(getattr(frames, name))
        if got != shape:
            raise ThrsimInputError(f"{where}: frames.{name} has shape {got}, expected {shape}")
    if t < 1:
        raise ThrsimInputError(f"{where}: a case needs at least one frame")
    energy_shape = np.shape(frames.energy)
    if len(energy_shape) != 2 or energy_shape[0] != t or energy_shape[1] != len(frames.energy_names):
        raise ThrsimInputError(
            f"{where}: frames.energy has shape {energy_shape}, expected ({t}, {len(frames.energy_names)}) for names {frames.energy_names}"
        )
    missing = [n for n in REQUIRED_ENERGIES if n not in frames.energy_names]
    if missing:
        raise ThrsimInputError(f"{where}: energy names lack {', '.join(missing)}")
    for name, trailing in OPTIONAL_PER_FRAME.items():
        data = getattr(frames, name)
        if data is not None and np.shape(data) != (t, *trailing):
            raise ThrsimInputError(f"{where}: frames.{name} has shape {np.shape(data)}, expected {(t, *trailing)}")


def _per_frame_dataset(group: h5py.Group, name: str, data: np.ndarray, dtype) -> None:
    data = np.ascontiguousarray(data, dtype=dtype)
    chunks = (1,) + data.shape[1:] if data.ndim > 1 else (max(1, min(len(data), 4096)),)
    group.create_dataset(name, data=data, chunks=chunks, **_COMPRESSION)


def write_case(
    path: str | os.PathLike,
    mesh: TetMesh,
    frames: CaseFrames,
    reamer_axis,
    *,
    inclination_deg: float,
    anteversion_deg: float,
    force_n: float,
    omega_rad_s: float,
    frame_dt_s: float,
    config: dict,
    extra_attrs: dict | None = None,
) -> Path:
    """Write one case file atomically (temporary name beside ``path``, fsync, rename); return ``path``."""
    path = Path(path)
    where = str(path)
    _check_frames(frames, mesh, where)
    axis = np.asarray(reamer_axis, dtype=np.float64).reshape(-1)
    if axis.shape != (3,):
        raise ThrsimInputError(f"{where}: reamer_axis must have 3 components, got {axis.shape}")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ThrsimInputError(f"{where}: output folder {folder} does not exist")
    config_text = json.dumps(config, sort_keys=True, default=json_default)
    with atomic_path(path, suffix=".tmp") as tmp:
        with hdf5_in_memory(tmp) as f:
            attrs = {
                "format": CASE_FORMAT,
                "version": CASE_VERSION,
                "inclination_deg": float(inclination_deg),
                "anteversion_deg": float(anteversion_deg),
                "force_n": float(force_n),
                "omega_rad_s": float(omega_rad_s),
                "frame_dt_s": float(frame_dt_s),
                "config": config_text,
                "config_hash": config_hash(json.loads(config_text)),
                "versions": json.dumps(package_versions()),
                "thrsim_version": __version__,
                "frames": frames.n_frames,
                "elements": mesh.n_tets,
            }
            for key, value in (extra_attrs or {}).items():
                value = attr_value(value)
                if key in ("frames", "elements"):  # a solver summary repeats them: the data decide
                    continue
                if key in attrs and attrs[key] != value:
                    raise ThrsimInputError(f"{where}: extra attribute {key!r}={value!r} contradicts the case's {attrs[key]!r}")
                attrs[key] = value
            f.attrs.update(attrs)
            write_mesh_group(f.create_group("mesh"), mesh)
            g = f.create_group("frames")
            g.create_dataset("time", data=np.asarray(frames.time, dtype=np.float64))
            _per_frame_dataset(g, "status", frames.status, np.uint8)
            _per_frame_dataset(g, "peeq", frames.peeq, np.float32)
            _per_frame_dataset(g, "von_mises", frames.von_mises, np.float32)
            for name in OPTIONAL_PER_ELEMENT:
                if getattr(frames, name) is not None:
                    _per_frame_dataset(g, name, getattr(frames, name), np.float32)
            g.create_dataset("reamer_position", data=np.asarray(frames.reamer_position, dtype=np.float64))
            g.create_dataset("reamer_axis", data=axis)
            energy = g.create_dataset("energy", data=np.asarray(frames.energy, dtype=np.float64))
            energy.attrs["names"] = [str(n) for n in frames.energy_names]
            for name in OPTIONAL_PER_FRAME:
                if getattr(frames, name) is not None:
                    g.create_dataset(name, data=np.asarray(getattr(frames, name), dtype=np.float64))
    return path


def decode_attrs(raw: h5py.AttributeManager) -> dict[str, Any]:
    attrs: dict[str, Any] = {}
    for key, value in raw.items():
        if isinstance(value, bytes):
            value = value.decode()
        if isinstance(value, np.generic):
            value = value.item()
        if key in ("config", "versions") and isinstance(value, str):
            try:
                value = json.loads(value)
            except ValueError:
                pass
        attrs[key] = value
    return attrs


def _energy_names(dataset: h5py.Dataset) -> tuple[str, ...]:
    names = dataset.attrs.get("names", ())
    return tuple(n.decode() if isinstance(n, bytes) else str(n) for n in np.atleast_1d(names))


def _open(path: Path) -> h5py.File:
    if not path.exists():
        raise ThrsimInputError(f"{path}: no such file")
    try:
        return h5py.File(path, "r")
    except OSError as error:
        raise ThrsimInputError(f"{path}: not a readable HDF5 file ({error})") from None


def read_case(path: str | os.PathLike) -> Case:
    """Read a whole case into memory (use :class:`CaseReader` to stream frames instead)."""
    path = Path(path)
    with _open(path) as f:
        if f.attrs.get("format") not in (CASE_FORMAT, CASE_FORMAT.encode()):
            raise ThrsimInputError(f"{path}: not a thrsim case file (format attribute {f.attrs.get('format')!r})")
        g = group_at(f, "frames", path)
        per_frame = {
            name: read_dataset(g, name, path, shape=(None, *trailing)) for name, trailing in _PER_FRAME_SHAPES.items() if name in g
        }
        frames = CaseFrames(
            time=read_dataset(g, "time", path, "f", (None,)),
            status=read_dataset(g, "status", path, "iu", (None, None)),
            peeq=read_dataset(g, "peeq", path, "f", (None, None)),
            von_mises=read_dataset(g, "von_mises", path, "f", (None, None)),
            reamer_position=read_dataset(g, "reamer_position", path, "f", (None, 3)),
            energy=read_dataset(g, "energy", path, "f", (None, None)),
            energy_names=_energy_names(g["energy"]),
            **{name: per_frame.get(name) for name in OPTIONAL_PER_FRAME},
            **{name: read_dataset(g, name, path, "f", (None, None)) if name in g else None for name in OPTIONAL_PER_ELEMENT},
        )
        mesh = read_mesh_group(group_at(f, "mesh", path))
        return Case(
            path=path, mesh=mesh, frames=frames, reamer_axis=read_dataset(g, "reamer_axis", path, "f", (3,)), attrs=decode_attrs(f.attrs)
        )


class CaseReader:
    """Open a case file and read single frames on demand (one chunk per per-element dataset)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._file = _open(self.path)
        try:
            self.attrs = decode_attrs(self._file.attrs)
            g = group_at(self._file, "frames", self.path)
            self._frames = g
            status = dataset_at(g, "status", self.path)
            check_dataset(status, self.path, "iu", (None, None))
            self.n_frames, self.n_elements = (int(n) for n in status.shape)
            for name in (*PER_ELEMENT, *OPTIONAL_PER_ELEMENT):
                if name in g or name in PER_ELEMENT:
                    check_dataset(dataset_at(g, name, self.path), self.path, "fiu", (self.n_frames, self.n_elements))
            self.time = read_dataset(g, "time", self.path, "f", (self.n_frames,))
            self.reamer_position = read_dataset(g, "reamer_position", self.path, "f", (self.n_frames, 3))
            self.reamer_axis = read_dataset(g, "reamer_axis", self.path, "f", (3,))
            self.energy = read_dataset(g, "energy", self.path, "f", (self.n_frames, None))
            self.energy_names = _energy_names(g["energy"])
            self.contact_force = read_dataset(g, "contact_force", self.path, "f", (self.n_frames, 3)) if "contact_force" in g else None
            self.reamer_axial = read_dataset(g, "reamer_axial", self.path, "f", (self.n_frames, 3)) if "reamer_axial" in g else None
            self.reaction_force = read_dataset(g, "reaction_force", self.path, "f", (self.n_frames, 3)) if "reaction_force" in g else None
            self.motor_torque = read_dataset(g, "motor_torque", self.path, "f", (self.n_frames,)) if "motor_torque" in g else None
        except ThrsimInputError:
            self._file.close()
            raise
        self._mesh: TetMesh | None = None

    @property
    def mesh(self) -> TetMesh:
        if self._mesh is None:
            self._mesh = read_mesh_group(group_at(self._file, "mesh", self.path))
        return self._mesh

    def series(self, name: str) -> np.ndarray | None:
        """A whole ``/frames`` dataset (every frame, checked), or None where this case lacks it."""
        return read_dataset(self._frames, name, self.path) if name in self._frames else None

    def frame(self, t: int) -> dict[str, np.ndarray]:
        """status, peeq and von_mises of frame ``t`` (and damage where the case has it), plus its
        time and reamer position."""
        if not -self.n_frames <= t < self.n_frames:
            raise IndexError(f"{self.path}: frame {t} out of range (0..{self.n_frames - 1})")
        g = self._frames
        return {
            "time": self.time[t],
            "status": g["status"][t],
            "peeq": g["peeq"][t],
            "von_mises": g["von_mises"][t],
            "reamer_position": self.reamer_position[t],
            **{name: g[name][t] for name in OPTIONAL_PER_ELEMENT if name in g},
        }

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> CaseReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def file_sha256(path: str | os.PathLike, block: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(block):
            digest.update(chunk)
    return digest.hexdigest()


def data_digest(path: str | os.PathLike) -> str:
    """SHA-256 over every dataset's dtype, shape and values (not attrs, not HDF5 layout bytes).

    Two runs of the same case give the same digest whatever their wall times or versions
    attributes: this is what "identical results" compares.
    """
    digest = hashlib.sha256()
    with _open(Path(path)) as f:
        names: list[str] = []
        f.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
        for name in sorted(names):
            data = np.ascontiguousarray(f[name][()])
            digest.update(f"{name}|{data.dtype.str}|{data.shape}|".encode())
            digest.update(data.tobytes())
    return digest.hexdigest()


_REQUIRED = (
    "mesh/nodes",
    "mesh/tets",
    "mesh/fixed_nodes",
    "frames/time",
    "frames/status",
    "frames/peeq",
    "frames/von_mises",
    "frames/reamer_position",
    "frames/reamer_axis",
    "frames/energy",
)
_REQUIRED_ATTRS = ("version", "inclination_deg", "anteversion_deg", "force_n", "omega_rad_s", "frame_dt_s", "config")


def validate_case(path: str | os.PathLike) -> dict[str, Any]:
    """Check a case file's format, then the physical sense of its frames; return a summary or
    raise ThrsimInputError naming the file and the first problem.

    Format (:func:`_check_format`): the format attribute, every required dataset and attribute,
    consistent shapes, integer dtypes, node indices that exist, finite values, time strictly
    increasing. History (:func:`_check_history`): status only 0/1, frame 0 intact (every element
    active, no plastic strain; a pre-reamed or chained case's prepared bone excepted), no negative PEEQ or von Mises stress, a removed element never
    reappears, PEEQ never decreases for an element still active.
    """
    path = Path(path)
    with _open(path) as f:
        n_nodes, n_el, n_frames, names = _check_format(f, path)
        attrs = decode_attrs(f.attrs)
        history = _check_history(f["frames"], path, n_frames, n_el, prepared=_prepared(attrs))
    removed_per_frame = history["removed_per_frame"]
    summary = {
        "path": str(path),
        "format": CASE_FORMAT,
        "version": attrs.get("version"),
        "frames": int(n_frames),
        "elements": int(n_el),
        "nodes": int(n_nodes),
        "removed": removed_per_frame[-1],
        "removed_fraction": removed_per_frame[-1] / n_el if n_el else 0.0,
        "removed_per_frame": removed_per_frame,
        "peeq_max": history["peeq_max"],
        "von_mises_min_pa": history["von_mises_min_pa"],
        "von_mises_max_pa": history["von_mises_max_pa"],
        "energy_names": list(names),
        "inclination_deg": attrs.get("inclination_deg"),
        "anteversion_deg": attrs.get("anteversion_deg"),
        "force_n": attrs.get("force_n"),
        "config_hash": attrs.get("config_hash"),
        "solution_hash": solution_hash(attrs["config"]) if isinstance(attrs.get("config"), dict) else None,
        "thrsim_version": attrs.get("thrsim_version"),
    }
    for key in ("end_reason", "perforated_frame", "seconds_per_frame"):
        if key in attrs:
            summary[key] = attrs[key]
    return summary


def solution_hash(config: dict) -> str:
    """Hash of what decides a case's result: its configuration without the solver's thread count
    (the solver's result does not depend on it), so a file solved on other threads is the same case."""
    solver = {key: value for key, value in (config.get("solver") or {}).items() if key != "threads"}
    return config_hash({**config, "solver": solver})


def file_solution_hash(path: str | os.PathLike) -> str | None:
    """:func:`solution_hash` of the configuration a case file was solved with (None if it records none)."""
    with _open(Path(path)) as f:
        config = decode_attrs(f.attrs).get("config")
    return solution_hash(config) if isinstance(config, dict) else None


def _check_format(f: h5py.File, path: Path) -> tuple[int, int, int, tuple[str, ...]]:
    """The file's layout: returns (nodes, elements, frames, energy names) or raises."""
    fmt = f.attrs.get("format")
    if isinstance(fmt, bytes):
        fmt = fmt.decode()
    if fmt != CASE_FORMAT:
        raise ThrsimInputError(f"{path}: not a thrsim case file (format attribute {fmt!r}, expected {CASE_FORMAT!r})")
    missing = [name for name in _REQUIRED if name not in f or not isinstance(f[name], h5py.Dataset)]
    if missing:
        raise ThrsimInputError(f"{path}: missing dataset /{missing[0]}" + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""))
    for name in (*_REQUIRED, *(f"frames/{name}" for name in (*OPTIONAL_PER_FRAME, *OPTIONAL_PER_ELEMENT) if name in f["frames"])):
        check_dataset(dataset_at(f, name, path), path)  # numbers, within the size thrsim reads
    missing_attrs = [a for a in _REQUIRED_ATTRS if a not in f.attrs]
    if missing_attrs:
        raise ThrsimInputError(f"{path}: missing attribute {missing_attrs[0]!r}")
    nodes, tets, fixed = f["mesh/nodes"], f["mesh/tets"], f["mesh/fixed_nodes"]
    g = f["frames"]
    if nodes.ndim != 2 or nodes.shape[1] != 3:
        raise ThrsimInputError(f"{path}: /mesh/nodes has shape {nodes.shape}, expected (N, 3)")
    if tets.ndim != 2 or tets.shape[1] != 4:
        raise ThrsimInputError(f"{path}: /mesh/tets has shape {tets.shape}, expected (E, 4)")
    n_nodes, n_el = nodes.shape[0], tets.shape[0]
    n_frames = g["time"].shape[0] if g["time"].ndim == 1 else -1
    if n_frames < 1:
        raise ThrsimInputError(f"{path}: /frames/time must be a non-empty (T,) array, got shape {g['time'].shape}")
    expected = {
        "status": (n_frames, n_el),
        "peeq": (n_frames, n_el),
        "von_mises": (n_frames, n_el),
        "reamer_position": (n_frames, 3),
        "reamer_axis": (3,),
    }
    expected.update({name: (n_frames, *trailing) for name, trailing in OPTIONAL_PER_FRAME.items() if name in g})
    for name, shape in expected.items():
        if g[name].shape != shape:
            raise ThrsimInputError(f"{path}: /frames/{name} has shape {g[name].shape}, expected {shape} (T={n_frames}, E={n_el})")
    energy = g["energy"]
    names = _energy_names(energy)
    if energy.ndim != 2 or energy.shape != (n_frames, len(names)):
        raise ThrsimInputError(
            f"{path}: /frames/energy has shape {energy.shape}, expected ({n_frames}, {len(names)}) for names {list(names)}"
        )
    lacking = [n for n in REQUIRED_ENERGIES if n not in names]
    if lacking:
        raise ThrsimInputError(f"{path}: /frames/energy lacks {', '.join(lacking)} (names {list(names)})")
    for name, kind in (("mesh/tets", "i"), ("mesh/fixed_nodes", "i"), ("frames/status", "u")):
        if f[name].dtype.kind not in (kind, "u" if kind == "i" else kind):
            raise ThrsimInputError(f"{path}: /{name} has dtype {f[name].dtype}, expected integers")

    tets_v = tets[()]
    if n_el and (tets_v.min() < 0 or tets_v.max() >= n_nodes):
        raise ThrsimInputError(f"{path}: /mesh/tets refers to nodes that do not exist")
    fixed_v = fixed[()]
    if len(fixed_v) and (fixed_v.min() < 0 or fixed_v.max() >= n_nodes):
        raise ThrsimInputError(f"{path}: /mesh/fixed_nodes refers to nodes that do not exist")
    for name in ("mesh/nodes", "frames/time", "frames/reamer_position", "frames/reamer_axis", "frames/energy") + tuple(
        f"frames/{name}" for name in OPTIONAL_PER_FRAME if name in g
    ):
        values = f[name][()]
        if not np.isfinite(values).all():
            raise ThrsimInputError(f"{path}: /{name} holds NaN or infinite values")
    time = g["time"][()]
    if n_frames > 1 and not np.all(np.diff(time) > 0):
        raise ThrsimInputError(f"{path}: /frames/time is not strictly increasing")
    return n_nodes, n_el, n_frames, names


def _prepared(attrs: dict[str, Any]) -> str | None:
    """How a case's bone was prepared before its frame 0: "pre_ream" (elements already gone),
    "start_from" (elements gone and plastic strain carried), None (intact)."""
    if attrs.get("start_from"):
        return "start_from"
    if attrs.get("pre_ream_mm") is not None:
        return "pre_ream"
    return None


def _check_history(g: h5py.Group, path: Path, n_frames: int, n_el: int, prepared: str | None = None) -> dict[str, Any]:
    """The per-element frames make physical sense, read one frame at a time; returns the
    removed count per frame, the largest PEEQ and the von Mises range. A prepared bone
    (``prepared``: see :func:`_prepared`) may start with elements gone, and a chained one with
    plastic strain."""
    status_ds, peeq_ds, vm_ds = g["status"], g["peeq"], g["von_mises"]
    damage_ds = {name: g[name] for name in OPTIONAL_PER_ELEMENT if name in g}
    prev_damage: dict[str, np.ndarray] = {}
    prev_status = prev_peeq = np.zeros(0)  # frame 0 sets them before any later frame reads them
    removed_per_frame: list[int] = []
    peeq_max = 0.0
    vm_min, vm_max = np.inf, -np.inf
    for t in range(n_frames):
        status = status_ds[t]
        peeq = peeq_ds[t].astype(np.float64)
        vm = vm_ds[t].astype(np.float64)
        if not (np.isfinite(peeq).all() and np.isfinite(vm).all()):
            raise ThrsimInputError(f"{path}: frame {t}: PEEQ or von Mises holds NaN or infinite values")
        if np.any(status > 1):
            raise ThrsimInputError(f"{path}: frame {t}: status values other than 0 and 1")
        if peeq.min(initial=0.0) < 0 or vm.min(initial=0.0) < 0:
            raise ThrsimInputError(f"{path}: frame {t}: negative PEEQ or von Mises stress")
        if t == 0:
            if not np.all(status == 1) and prepared is None:
                raise ThrsimInputError(f"{path}: frame 0 is not intact ({int((status == 0).sum())} element(s) removed)")
            if peeq.max(initial=0.0) > 0 and prepared != "start_from":
                raise ThrsimInputError(f"{path}: frame 0 is not intact (PEEQ up to {peeq.max():.3g})")
        else:
            back = (prev_status == 0) & (status == 1)
            if back.any():
                raise ThrsimInputError(
                    f"{path}: frame {t}: {int(back.sum())} removed element(s) reappear (first: element {int(np.flatnonzero(back)[0])})"
                )
            live = status == 1
            tol = 1e-6 * np.maximum(1.0, np.abs(prev_peeq))
            dropped = live & (peeq < prev_peeq - tol)
            if dropped.any():
                first = int(np.flatnonzero(dropped)[0])
                raise ThrsimInputError(
                    f"{path}: frame {t}: PEEQ decreases for {int(dropped.sum())} element(s) (first: element {first}, "
                    f"{prev_peeq[first]:.6g} -> {peeq[first]:.6g})"
                )
        for name, dataset in damage_ds.items():
            if dataset.shape != (n_frames, n_el):
                raise ThrsimInputError(f"{path}: /frames/{name} has shape {dataset.shape}, expected {(n_frames, n_el)}")
            value = dataset[t].astype(np.float64)
            upper = 1.0 + 1e-6 if name == "damage" else np.inf
            if not np.isfinite(value).all() or value.min(initial=0.0) < 0 or value.max(initial=0.0) > upper:
                raise ThrsimInputError(f"{path}: frame {t}: {name} outside [0, {'1' if name == 'damage' else '∞'}) or not finite")
            if t > 0 and (dropped := (status == 1) & (value < prev_damage[name] - 1e-6)).any():
                raise ThrsimInputError(
                    f"{path}: frame {t}: {name} decreases for {int(dropped.sum())} element(s) (first: element {int(np.flatnonzero(dropped)[0])})"
                )
            prev_damage[name] = value
        removed_per_frame.append(int(n_el - int(status.sum())))
        peeq_max = max(peeq_max, float(peeq.max(initial=0.0)))
        if n_el:
            vm_min, vm_max = min(vm_min, float(vm.min())), max(vm_max, float(vm.max()))
        prev_status, prev_peeq = status, peeq
    return {
        "removed_per_frame": removed_per_frame,
        "peeq_max": peeq_max,
        "von_mises_min_pa": vm_min if n_el else 0.0,
        "von_mises_max_pa": vm_max if n_el else 0.0,
    }
