"""The session journal: every input of a live session on disk as it arrives, so a crash loses at most the last second.

One append-only file per live session, ``<session id>.journal`` beside the finished session
files, of length- and CRC-32-framed records (format: :class:`JournalWriter`). Killing the process
loses nothing appended, a power cut at most ``sync_interval_s``; reading stops at the first torn
record, and everything before it is intact. The writer holds an exclusive ``flock`` on the file
while it lives, so a journal nobody holds belongs to a session that was interrupted.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import struct
import threading
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from thrsim.atomic import fsync_folder
from thrsim.errors import ThrsimInputError

log = logging.getLogger(__name__)

FORMAT = "thrsim-journal"
FORMAT_VERSION = 1
SUFFIX = ".journal"
#: the longest pose device name: OpenIGTLink's header field (the session file stores it at this width)
DEVICE_BYTES = 20

_FRAME = struct.Struct("<II")  # body length, CRC-32 of the body
#: no record is longer (a control is at most 16 KiB): a longer length is a garbled frame, not a read of gigabytes
_MAX_BODY = 1 << 20
_TIME = struct.Struct("<d")
_POSE = struct.Struct("<d16d")
_FORCE = struct.Struct("<dd")


class JournalWriter:
    """Appends a live session's inputs to its journal file.

    One append-only file per live session, ``<session id>.journal`` in the sessions folder, beside the
    finished session files. Each record is a little-endian ``u32`` body length, the body's ``u32``
    CRC-32, then the body: one kind byte and its fields.

    * ``H`` header (first record): JSON object with ``format`` = "thrsim-journal", ``format_version``
      and ``session``, the session file's header attributes known at the start (``session_id``,
      ``mode``, ``started_utc``, ``settings``, ``versions``);
    * ``C`` control: f64 time, the control's JSON text;
    * ``P`` pose: f64 time, 16 f64 (the 4×4 matrix, row-major, metres), the device name (UTF-8);
    * ``F`` force: f64 time, f64 newton;
    * ``T`` tick (a trainer step): f64 time.

    Times are seconds from the session's start; an input's ``seq`` is its place among the input
    records (from 1), as in the session file. Each record reaches the operating system as it is
    appended, so killing the process loses nothing appended; a background thread fsyncs the file
    every ``sync_interval_s`` (≤ 1 s), so a power cut loses at most that much. Reading stops at the
    first torn record (cut short or failing its CRC): everything before it is intact.

    The writer holds an exclusive ``flock`` on the file while it lives and the kernel drops it when
    the process dies, so a journal nobody holds belongs to a session that was interrupted.
    """

    def __init__(self, path: Path, attrs: dict, sync_interval_s: float = 0.5):
        self.path = Path(path)
        self.sync_interval_s = sync_interval_s
        self.count = 0  # inputs appended (their last seq)
        self.ticks = 0
        self._waiting = bytearray()  # records the file refused (a full disk), written before the next ones
        self._failing = False
        try:
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND, 0o644)
        except OSError as error:
            raise ThrsimInputError(f"{self.path}: cannot create the session journal ({error.strerror or error})") from None
        fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # a file just created: nobody else holds it
        try:
            self._waiting += _record(b"H" + json.dumps({"format": FORMAT, "format_version": FORMAT_VERSION, "session": attrs}).encode())
            self.flush()
            os.fsync(self._fd)
            fsync_folder(self.path.parent)
        except OSError as error:
            os.close(self._fd)
            self.path.unlink()
            raise ThrsimInputError(f"{self.path}: cannot write the session journal ({error.strerror or error})") from None
        self._dirty = False
        self._closing = threading.Event()
        self._syncer = threading.Thread(target=self._sync_loop, name=f"journal {self.path.name}", daemon=True)
        self._syncer.start()

    def _append(self, body: bytes) -> None:
        """Write a record at once; if the file refuses it, keep it (and what follows) in memory, in
        order, until a write succeeds: the session goes on and its journal stays whole."""
        self._waiting += _record(body)
        try:
            self.flush()
        except OSError as error:
            if not self._failing:
                log.warning("%s: cannot write the session journal (%s): inputs wait in memory", self.path, error.strerror or error)
            self._failing = True

    def flush(self) -> None:
        """Write the records waiting in memory; OSError when the file still refuses them."""
        while self._waiting:
            written = os.write(self._fd, self._waiting)
            del self._waiting[:written]
            self._dirty = True
        if self._failing:
            log.warning("%s: the session journal writes again", self.path)
            self._failing = False

    def _sync_loop(self) -> None:
        while not self._closing.wait(self.sync_interval_s):
            if self._dirty:
                self._dirty = False
                try:
                    os.fsync(self._fd)
                except OSError as error:
                    log.warning("%s: fsync failed (%s); the journal goes on", self.path, error.strerror or error)

    def control(self, time_s: float, message: dict) -> None:
        self.count += 1
        self._append(b"C" + _TIME.pack(time_s) + json.dumps(message, separators=(",", ":")).encode())

    def pose(self, time_s: float, device: str, matrix: np.ndarray) -> None:
        name = device.encode()
        if len(name) > DEVICE_BYTES:
            raise ThrsimInputError(f"pose device name {device!r} is {len(name)} bytes, more than {DEVICE_BYTES}")
        self.count += 1
        self._append(b"P" + _POSE.pack(time_s, *np.asarray(matrix, dtype=float).reshape(16)) + name)

    def force(self, time_s: float, newton: float) -> None:
        self.count += 1
        self._append(b"F" + _FORCE.pack(time_s, newton))

    def tick(self, time_s: float) -> None:
        self.count += 1
        self.ticks += 1
        self._append(b"T" + _TIME.pack(time_s))

    def close(self, remove: bool = False) -> None:
        """Sync and close the journal; ``remove`` deletes it first (its session is saved, or had no inputs)."""
        if self._fd < 0:
            return
        self._closing.set()
        self._syncer.join()
        if remove:
            self.path.unlink()
            fsync_folder(self.path.parent)
        else:
            self.flush()
            os.fsync(self._fd)
        os.close(self._fd)  # releases the lock
        self._fd = -1


class Journal:
    """A journal read back: ``attrs`` (the session's header attributes), then its inputs in lived order
    as ``(kind, time_s, payload)`` (kind control, pose, force or tick; payloads as
    :meth:`thrsim.session.file.InputLog.replay`)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.torn = False  # set by a read that met a torn record
        with open(self.path, "rb") as handle:
            body = _read_record(handle)
        try:
            if body is None or body[:1] != b"H":
                raise ValueError("no header record")
            header = json.loads(body[1:])
            if not isinstance(header, dict) or header.get("format") != FORMAT or header.get("format_version") != FORMAT_VERSION:
                raise ValueError("a header of another format or version")
            if not isinstance(header.get("session"), dict):
                raise ValueError("no session attributes in the header")
        except ValueError as error:
            raise ThrsimInputError(f"{self.path}: not a thrsim session journal ({error})") from None
        self.attrs: dict = header["session"]

    def inputs(self) -> Iterator[tuple[str, float, Any]]:
        with open(self.path, "rb") as handle:
            _read_record(handle)  # the header
            while (body := _read_record(handle)) is not None:
                kind = body[:1]
                if kind == b"T":
                    yield "tick", _TIME.unpack_from(body, 1)[0], None
                elif kind == b"P":
                    time_s, *matrix = _POSE.unpack_from(body, 1)
                    yield "pose", time_s, (body[1 + _POSE.size :].decode(), np.array(matrix).reshape(4, 4))
                elif kind == b"C":
                    yield "control", _TIME.unpack_from(body, 1)[0], json.loads(body[1 + _TIME.size :])
                elif kind == b"F":
                    yield "force", *_FORCE.unpack_from(body, 1)
                else:
                    raise ThrsimInputError(f"{self.path}: unknown journal record kind {kind!r}")
            self.torn = handle.read(1) != b""


def _record(body: bytes) -> bytes:
    return _FRAME.pack(len(body), zlib.crc32(body)) + body


def _read_record(handle) -> bytes | None:
    """The next record's body; None at the end or at a torn record (the handle then rests at its start)."""
    start = handle.tell()
    frame = handle.read(_FRAME.size)
    if len(frame) == _FRAME.size:
        size, crc = _FRAME.unpack(frame)
        body = handle.read(size) if size <= _MAX_BODY else b""
        if len(body) == size and zlib.crc32(body) == crc:
            return body
    handle.seek(start)
    return None


@contextlib.contextmanager
def claimed(path: Path) -> Iterator[bool]:
    """Hold the journal at ``path`` for the block; yields False (holding nothing) when a live session
    of this process or another still writes it."""
    with open(path, "rb") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield False
            return
        yield True
