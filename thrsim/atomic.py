"""Write files to a temporary name in the target folder, fsync, then rename: never a half-written output.

A write that fails (a full disk, a file-size limit, an I/O error) raises :class:`ThrsimOutputError`
naming the output; the temporary file is removed and a previous file of that name is untouched.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from thrsim.errors import ThrsimInputError, ThrsimOutputError

if TYPE_CHECKING:
    import h5py


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
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix or "".join(target.suffixes) or ".tmp", dir=folder)
    except OSError as error:
        raise _output_error(error, target) from error
    os.close(fd)
    tmp = Path(tmp_name)
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; outputs get the usual permissions
        yield tmp
        # flush the data to disk before the rename publishes it, and the rename itself after
        with open(tmp, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, target)
        fsync_folder(folder)
    except OSError as error:
        if isinstance(error, ThrsimOutputError) or error.filename not in (None, tmp_name, tmp):
            raise  # already named, or about another file (an input read in the block)
        raise _output_error(error, target) from error
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def hdf5_in_memory(path: str | os.PathLike) -> Iterator[h5py.File]:
    """Yield a new HDF5 file built in memory; write it to ``path`` in one go if the block succeeds.

    Use it inside :func:`atomic_path`. HDF5 writing to disk keeps data and metadata in its own
    caches: on a full disk its close fails, h5py leaves the file open and the library crashes at
    interpreter exit (SIGSEGV). In memory, the file meets the disk in one Python write, whose
    failure is an ordinary OSError.
    """
    import h5py

    # the core driver without a backing store never touches the file of that name
    h5 = h5py.File(path, "w", driver="core", backing_store=False, block_size=1 << 20)
    try:
        yield h5
        h5.flush()
        image = h5.id.get_file_image()
    finally:
        h5.close()
    with open(path, "wb") as handle:
        handle.write(image)


@contextlib.contextmanager
def atomic_folder(target: str | os.PathLike) -> Iterator[Path]:
    """Yield a new temporary folder beside ``target``; it replaces ``target`` only if the block succeeds.

    A write that fails in the folder raises :class:`ThrsimOutputError` naming ``target``; the
    temporary folder is removed and a previous ``target`` is left as it was.
    """
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=parent))
    except OSError as error:
        raise _output_error(error, target) from error
    try:
        yield staging
        os.chmod(staging, 0o755)
        if target.exists():
            shutil.rmtree(target)
        os.replace(staging, target)
        fsync_folder(parent)
    except OSError as error:
        inside = error.filename is None or os.fspath(error.filename).startswith(os.fspath(staging))
        if isinstance(error, ThrsimOutputError) or not inside:
            raise
        raise _output_error(error, target) from error
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)


def _output_error(error: OSError, target: Path) -> ThrsimOutputError:
    return ThrsimOutputError(error.errno, error.strerror or str(error), str(target))


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
