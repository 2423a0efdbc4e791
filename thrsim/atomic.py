"""Write files to a temporary name in the target folder, fsync, then rename: never a half-written output."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from thrsim.errors import ThrsimInputError


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` only if the block succeeds.

    The temporary name keeps the target's suffix (writers such as meshio pick the format from it).
    """
    target = Path(target)
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise ThrsimInputError(f"{target}: output folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise ThrsimInputError(f"{target}: output folder {folder} is not writable")
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix or "".join(target.suffixes) or ".tmp", dir=folder)
    os.close(fd)
    tmp = Path(tmp_name)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; outputs get the usual permissions
    try:
        yield tmp
        # flush the data to disk before the rename publishes it, and the rename itself after
        with open(tmp, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, target)
        fsync_folder(folder)
    finally:
        if tmp.exists():
            tmp.unlink()


def fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (a no-op where folders cannot be synced)."""
    try:
        descriptor = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(descriptor)
    except OSError:
        pass  # some file systems do not sync folders; the rename is still atomic
    finally:
        os.close(descriptor)


def check_folder_creatable(folder: str | os.PathLike, what: str = "output folder") -> None:
    """Refuse, before any work, a folder that cannot be used or created as ``mkdir -p`` would.

    ``folder`` may exist (then it must be a writable directory) or be created: each part of its
    path that exists must be a directory (a file or a dangling symbolic link in the way is
    refused) and the deepest existing one must be writable. Raises :class:`ThrsimInputError`.
    """
    folder = Path(folder)
    if folder.is_dir():
        if not os.access(folder, os.W_OK | os.X_OK):
            raise ThrsimInputError(f"{folder}: {what} is not writable")
        return
    probe = folder
    while True:
        if os.path.lexists(probe) and not probe.is_dir():
            kind = "a dangling symbolic link" if probe.is_symlink() and not probe.exists() else "not a directory"
            raise ThrsimInputError(f"{folder}: cannot create the {what}: {probe} is {kind}")
        if probe.is_dir():
            break
        if probe.parent == probe:
            break
        probe = probe.parent
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ThrsimInputError(f"{folder}: cannot create the {what}: {probe} is not writable")
