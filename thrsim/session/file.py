"""The session file: a trainer session's inputs (in arrival order) and each mode's outputs.

One HDF5 file per session (layout: :func:`write_session`): header attributes, the inputs
(controls, tracker poses, forces, ticks) with one ``seq`` counter over all of them, so a replay
applies them in the order they were lived, one group per mode that ran, and the questionnaire's
answers. While the session lives its inputs go to its journal (:mod:`thrsim.session.journal`),
not to memory; the file is written once, when the session ends, streamed from the journal into
chunked, compressed tables, to a temporary name that is then renamed (:mod:`thrsim.atomic`): a
crash mid-write leaves no half file, and the journal is removed only once the file is in place.
"""

from __future__ import annotations

import json
from array import array
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from thrsim.atomic import atomic_path, hdf5_in_memory
from thrsim.errors import ThrsimInputError
from thrsim.hdf5_checks import check_dataset
from thrsim.session.journal import DEVICE_BYTES

FORMAT = "thrsim-session"
FORMAT_VERSION = 1
_TEXT = h5py.string_dtype()


class _Column:
    """A growing numeric column in a compact buffer (``array``): a ten-minute session at 60 Hz
    holds ~36,000 ticks and as many poses, which Python tuples would make several times larger."""

    def __init__(self, typecode: str, width: int = 1, values=()):
        self.width = width
        self.data = array(typecode, values)

    def append(self, *values) -> None:
        self.data.extend(values)

    def __len__(self) -> int:
        return len(self.data) // self.width

    def numpy(self, dtype) -> np.ndarray:
        values = np.frombuffer(self.data, dtype=np.dtype(self.data.typecode)) if len(self.data) else np.zeros(0)
        return values.astype(dtype).reshape(-1, self.width) if self.width > 1 else values.astype(dtype)


class InputLog:
    """Every input of a session read back from its file, in compact columns; ``seq`` orders them all."""

    def __init__(self) -> None:
        self.controls: list[tuple[int, float, str]] = []
        self.devices: list[str] = []  # pose device names, stored as indices into this list
        self.pose_seq, self.pose_time, self.pose_device, self.pose_matrix = _Column("q"), _Column("d"), _Column("H"), _Column("d", 16)
        self.force_seq, self.force_time, self.force_newton = _Column("q"), _Column("d"), _Column("d")
        self.tick_seq, self.tick_time = _Column("q"), _Column("d")
        self._seq = 0

    def _next(self) -> int:
        self._seq += 1
        return self._seq

    def pose(self, time_s: float, device: str, matrix: np.ndarray) -> None:
        if device not in self.devices:
            self.devices.append(device)
        self.pose_seq.append(self._next())
        self.pose_time.append(time_s)
        self.pose_device.append(self.devices.index(device))
        self.pose_matrix.append(*np.asarray(matrix, dtype=float).ravel())

    @property
    def count(self) -> int:
        return self._seq

    def pose_devices(self) -> list[str]:
        return [self.devices[i] for i in self.pose_device.data]

    def replay(self) -> Iterator[tuple[str, float, Any]]:
        """(kind, time, payload) in lived order: kind is control, pose, force or tick."""
        matrices = self.pose_matrix.numpy(float).reshape(-1, 4, 4)
        merged = [(s, "control", t, json.loads(m)) for s, t, m in self.controls]
        merged += [
            (s, "pose", t, (self.devices[d], matrices[k]))
            for k, (s, t, d) in enumerate(zip(self.pose_seq.data, self.pose_time.data, self.pose_device.data, strict=True))
        ]
        merged += [(s, "force", t, f) for s, t, f in zip(self.force_seq.data, self.force_time.data, self.force_newton.data, strict=True)]
        merged += [(s, "tick", t, None) for s, t in zip(self.tick_seq.data, self.tick_time.data, strict=True)]
        for _, kind, time_s, payload in sorted(merged, key=lambda item: item[0]):
            yield kind, time_s, payload


@dataclass
class SessionFile:
    """A session read back: header attributes, inputs, and each mode group as nested dicts of arrays."""

    path: Path
    attrs: dict
    inputs: InputLog
    groups: dict[str, dict]

    @property
    def settings(self) -> dict:
        return json.loads(self.attrs["settings"])

    @property
    def versions(self) -> dict:
        return json.loads(self.attrs["versions"])


class _TableWriter:
    """One inputs table written as its rows arrive: resizable chunked columns, appended a chunk at a
    time, so a long session is written in bounded memory. Numeric and device columns are compressed."""

    CHUNK = 4096

    def __init__(self, group: h5py.Group, columns: dict[str, tuple[object, tuple[int, ...]]]):
        self.columns = {}
        for name, (dtype, shape) in columns.items():
            packed = {} if dtype is _TEXT else {"compression": "gzip", "compression_opts": 1, "shuffle": True}
            self.columns[name] = group.create_dataset(
                name, shape=(0, *shape), maxshape=(None, *shape), dtype=dtype, chunks=(self.CHUNK, *shape), **packed
            )
        self.rows: list[tuple] = []

    def append(self, *row) -> None:
        self.rows.append(row)
        if len(self.rows) == self.CHUNK:
            self.flush()

    def flush(self) -> None:
        if not self.rows:
            return
        for values, dataset in zip(zip(*self.rows, strict=True), self.columns.values(), strict=True):
            start = dataset.shape[0]
            dataset.resize(start + len(values), axis=0)
            dataset[start:] = np.array(values, dtype=object if dataset.dtype.kind == "O" else dataset.dtype)
        self.rows = []


def write_session(
    path: str | Path,
    attrs: dict,
    inputs: Iterable[tuple[str, float, Any]],
    mode_writers: dict[str, Callable[[h5py.Group], None]],
) -> Path:
    """Write the whole session atomically: ``inputs`` as ``(kind, time_s, payload)`` in lived order
    (a journal's :meth:`~thrsim.session.journal.Journal.inputs`); ``mode_writers`` fill one group per mode.

    Layout (HDF5, one file per session; times in seconds from the session's start, poses in metres):

    * attrs: ``format`` = "thrsim-session", ``format_version``, ``mode``, ``started_utc``,
      ``ended_utc``, ``duration_s``, ``settings`` (JSON), ``versions`` (JSON: thrsim, Python,
      numerical and web libraries, three.js), ``interrupted`` (true when the session never ended: the
      server stopped without saving it, and the next start closed it from its journal; files written
      before journals lack it and ended normally), ``trainee`` (the name or ID the page gave, absent
      when none was);
    * ``/inputs/controls``: ``seq``, ``time``, ``message`` (JSON text of each page control);
    * ``/inputs/poses``: ``seq``, ``time``, ``device`` (name), ``matrix`` (N×4×4) from the tracker;
    * ``/inputs/forces``: ``seq``, ``time``, ``newton``;
    * ``/inputs/ticks``: ``seq``, ``time`` of each trainer step;
    * one group per mode that ran (``/navigation``; reaming adds ``/reaming``), written and read by
      that mode's record class;
    * ``/questionnaire``, once the trainee answered the post-session questionnaire
      (:mod:`thrsim.session.questionnaire`).
    """
    path = Path(path)
    device = h5py.string_dtype("utf-8", DEVICE_BYTES)
    with atomic_path(path) as tmp:
        with hdf5_in_memory(tmp) as h5:
            h5.attrs.update({"format": FORMAT, "format_version": FORMAT_VERSION, **attrs})
            group = h5.create_group("inputs")
            seq, time = (np.int64, ()), (np.float64, ())
            tables = {
                "control": _TableWriter(group.create_group("controls"), {"seq": seq, "time": time, "message": (_TEXT, ())}),
                "pose": _TableWriter(
                    group.create_group("poses"), {"seq": seq, "time": time, "device": (device, ()), "matrix": (np.float64, (4, 4))}
                ),
                "force": _TableWriter(group.create_group("forces"), {"seq": seq, "time": time, "newton": (np.float64, ())}),
                "tick": _TableWriter(group.create_group("ticks"), {"seq": seq, "time": time}),
            }
            for number, (kind, time_s, payload) in enumerate(inputs, start=1):
                if kind == "control":
                    tables[kind].append(number, time_s, json.dumps(payload, separators=(",", ":")))
                elif kind == "pose":
                    tables[kind].append(number, time_s, payload[0].encode(), payload[1])
                elif kind == "force":
                    tables[kind].append(number, time_s, payload)
                else:
                    tables[kind].append(number, time_s)
            for table in tables.values():
                table.flush()
            for mode, writer in mode_writers.items():
                writer(h5.create_group(mode))
    return path


def is_interrupted(path: Path) -> bool:
    """Whether the session file at ``path`` was closed from its journal after a crash (False when unreadable)."""
    try:
        with h5py.File(path, "r") as h5:
            return bool(h5.attrs.get("interrupted", False))
    except (OSError, ValueError):
        return False


def _read_group(group: h5py.Group, source: Path) -> dict:
    out: dict = {"attrs": dict(group.attrs)}
    for name, item in group.items():
        if isinstance(item, h5py.Group):
            out[name] = _read_group(item, source)
            continue
        check_dataset(item, source, kinds=None)  # within the size thrsim reads, before it is read
        if item.dtype.kind == "O" or h5py.check_string_dtype(item.dtype) is not None:
            out[name] = [v.decode() if isinstance(v, bytes) else str(v) for v in item[()]]
        else:
            out[name] = item[()]
    return out


def read_session(path: str | Path) -> SessionFile:
    """Read a session file; ThrsimInputError (one line) if it is missing, garbled, or of another format version."""
    path = Path(path)
    if not path.is_file():
        raise ThrsimInputError(f"{path}: no such session file")
    try:
        with h5py.File(path, "r") as h5:
            attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in h5.attrs.items()}
            if attrs.get("format") != FORMAT:
                raise ThrsimInputError(f"{path}: not a thrsim session file (format {attrs.get('format')!r})")
            version = int(attrs.get("format_version", -1))
            if version != FORMAT_VERSION:
                raise ThrsimInputError(f"{path}: session file format version {version}; this thrsim reads version {FORMAT_VERSION}")
            data = {name: _read_group(group, path) for name, group in h5.items() if isinstance(group, h5py.Group)}
    except ThrsimInputError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as error:
        raise ThrsimInputError(f"{path}: unreadable session file ({str(error).splitlines()[0]})") from None
    raw = data.pop("inputs", None)
    if raw is None:
        raise ThrsimInputError(f"{path}: session file has no inputs group")
    try:
        inputs = InputLog()
        inputs.controls = list(
            zip(raw["controls"]["seq"].tolist(), raw["controls"]["time"].tolist(), raw["controls"]["message"], strict=True)
        )
        poses = raw["poses"]
        for seq, time_s, device, matrix in zip(
            poses["seq"].tolist(), poses["time"].tolist(), poses["device"], np.asarray(poses["matrix"]).reshape(-1, 4, 4), strict=True
        ):
            inputs._seq = seq - 1
            inputs.pose(time_s, device, matrix)
        forces, ticks = raw["forces"], raw["ticks"]
        if len({len(forces[k]) for k in ("seq", "time", "newton")}) > 1 or len(ticks["seq"]) != len(ticks["time"]):
            raise ValueError("columns of unequal length")
        inputs.force_seq, inputs.force_time, inputs.force_newton = (
            _Column(t, 1, forces[k].tolist()) for t, k in (("q", "seq"), ("d", "time"), ("d", "newton"))
        )
        inputs.tick_seq, inputs.tick_time = _Column("q", 1, ticks["seq"].tolist()), _Column("d", 1, ticks["time"].tolist())
    except (KeyError, ValueError, TypeError) as error:
        raise ThrsimInputError(f"{path}: session file lacks or garbles an inputs table ({error})") from None
    for _, _, message in inputs.controls:
        try:
            json.loads(message)
        except (ValueError, RecursionError):
            raise ThrsimInputError(f"{path}: a recorded control is not JSON (or nests too deeply)") from None
    every = [s for s, _, _ in inputs.controls] + list(inputs.pose_seq.data) + list(inputs.force_seq.data) + list(inputs.tick_seq.data)
    inputs._seq = max(every, default=0)
    return SessionFile(path=path, attrs=attrs, inputs=inputs, groups=data)
