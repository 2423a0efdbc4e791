"""The session file: a trainer session's inputs (in arrival order) and each mode's outputs.

Layout (HDF5, one file per session; times in seconds from the session's start, poses in metres):

* attrs: ``format`` = "thrsim-session", ``format_version``, ``mode``, ``started_utc``,
  ``ended_utc``, ``duration_s``, ``settings`` (JSON), ``versions`` (JSON: thrsim, Python,
  numerical and web libraries, three.js);
* ``/inputs/controls``: ``seq``, ``time``, ``message`` (JSON text of each page control);
* ``/inputs/poses``: ``seq``, ``time``, ``device`` (name), ``matrix`` (N×4×4) from the tracker;
* ``/inputs/forces``: ``seq``, ``time``, ``newton``;
* ``/inputs/ticks``: ``seq``, ``time`` of each trainer step;
* one group per mode that ran (``/navigation``; reaming adds ``/reaming``), written and read by
  that mode's record class.

``seq`` is one counter over all inputs, so a replay applies them in the order they were lived.
The file is written once, when the session ends, to a temporary name and renamed
(:mod:`thrsim.atomic`): a crash mid-write leaves no half file.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from thrsim.atomic import atomic_path
from thrsim.errors import ThrsimInputError

FORMAT = "thrsim-session"
FORMAT_VERSION = 1
_TEXT = h5py.string_dtype()


@dataclass
class InputLog:
    """Every input of a live session, appended as it arrives (cheap: Python lists)."""

    controls: list[tuple[int, float, str]] = field(default_factory=list)
    poses: list[tuple[int, float, str, np.ndarray]] = field(default_factory=list)
    forces: list[tuple[int, float, float]] = field(default_factory=list)
    ticks: list[tuple[int, float]] = field(default_factory=list)
    _seq: int = 0

    def _next(self) -> int:
        self._seq += 1
        return self._seq

    def control(self, time_s: float, message: dict) -> None:
        self.controls.append((self._next(), time_s, json.dumps(message, separators=(",", ":"))))

    def pose(self, time_s: float, device: str, matrix: np.ndarray) -> None:
        self.poses.append((self._next(), time_s, device, np.array(matrix, dtype=float)))

    def force(self, time_s: float, newton: float) -> None:
        self.forces.append((self._next(), time_s, float(newton)))

    def tick(self, time_s: float) -> None:
        self.ticks.append((self._next(), time_s))

    @property
    def count(self) -> int:
        return self._seq

    def replay(self) -> Iterator[tuple[str, float, object]]:
        """(kind, time, payload) in lived order: kind is control, pose, force or tick."""
        merged = [(s, "control", t, json.loads(m)) for s, t, m in self.controls]
        merged += [(s, "pose", t, (d, m)) for s, t, d, m in self.poses]
        merged += [(s, "force", t, f) for s, t, f in self.forces]
        merged += [(s, "tick", t, None) for s, t in self.ticks]
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


def _write_table(group: h5py.Group, columns: dict[str, np.ndarray]) -> None:
    for name, values in columns.items():
        group.create_dataset(name, data=values)


def write_session(
    path: str | Path,
    attrs: dict,
    inputs: InputLog,
    mode_writers: dict[str, Callable[[h5py.Group], None]],
) -> Path:
    """Write the whole session atomically; ``mode_writers`` fill one group per mode."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as h5:
            h5.attrs.update({"format": FORMAT, "format_version": FORMAT_VERSION, **attrs})
            group = h5.create_group("inputs")
            _write_table(
                group.create_group("controls"),
                {
                    "seq": np.array([c[0] for c in inputs.controls], dtype=np.int64),
                    "time": np.array([c[1] for c in inputs.controls], dtype=float),
                    "message": np.array([c[2] for c in inputs.controls], dtype=object).astype(_TEXT),
                },
            )
            _write_table(
                group.create_group("poses"),
                {
                    "seq": np.array([p[0] for p in inputs.poses], dtype=np.int64),
                    "time": np.array([p[1] for p in inputs.poses], dtype=float),
                    "device": np.array([p[2] for p in inputs.poses], dtype=object).astype(_TEXT),
                    "matrix": np.array([p[3] for p in inputs.poses], dtype=float).reshape(-1, 4, 4),
                },
            )
            _write_table(
                group.create_group("forces"),
                {
                    "seq": np.array([f[0] for f in inputs.forces], dtype=np.int64),
                    "time": np.array([f[1] for f in inputs.forces], dtype=float),
                    "newton": np.array([f[2] for f in inputs.forces], dtype=float),
                },
            )
            _write_table(
                group.create_group("ticks"),
                {
                    "seq": np.array([t[0] for t in inputs.ticks], dtype=np.int64),
                    "time": np.array([t[1] for t in inputs.ticks], dtype=float),
                },
            )
            for mode, writer in mode_writers.items():
                writer(h5.create_group(mode))
    return path


def _read_group(group: h5py.Group) -> dict:
    out: dict = {"attrs": dict(group.attrs)}
    for name, item in group.items():
        if isinstance(item, h5py.Group):
            out[name] = _read_group(item)
        elif item.dtype.kind == "O" or h5py.check_string_dtype(item.dtype) is not None:
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
            data = {name: _read_group(group) for name, group in h5.items()}
    except ThrsimInputError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as error:
        raise ThrsimInputError(f"{path}: unreadable session file ({str(error).splitlines()[0]})") from None
    raw = data.pop("inputs", None)
    if raw is None:
        raise ThrsimInputError(f"{path}: session file has no inputs group")
    try:
        inputs = InputLog(
            controls=list(zip(raw["controls"]["seq"].tolist(), raw["controls"]["time"].tolist(), raw["controls"]["message"])),
            poses=list(zip(raw["poses"]["seq"].tolist(), raw["poses"]["time"].tolist(), raw["poses"]["device"], list(raw["poses"]["matrix"]))),
            forces=list(zip(raw["forces"]["seq"].tolist(), raw["forces"]["time"].tolist(), raw["forces"]["newton"].tolist())),
            ticks=list(zip(raw["ticks"]["seq"].tolist(), raw["ticks"]["time"].tolist())),
        )
    except KeyError as error:
        raise ThrsimInputError(f"{path}: session file lacks inputs table {error}") from None
    inputs._seq = max((s for s, *_ in inputs.controls + inputs.poses + inputs.forces + inputs.ticks), default=0)
    return SessionFile(path=path, attrs=attrs, inputs=inputs, groups=data)
