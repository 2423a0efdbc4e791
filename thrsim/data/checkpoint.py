"""Checkpoints of a running case: a long case resumes from its last checkpointed frame after a kill.

A checkpoint is one HDF5 file beside the case file (``CASE.h5.resume``), written atomically
(temporary name, fsync, rename) from the solver's :meth:`~thrsim.physics.reaming_case.ReamingCase.snapshot`:
the bone's and the reamer's state and every frame recorded so far. It names the thrsim version and
the hash of the case's full configuration; a checkpoint of another case or another thrsim is not
resumed. Resuming gives the case file an uninterrupted run would have written, bit for bit.
"""

from __future__ import annotations

import time
from pathlib import Path

import h5py
import numpy as np

from thrsim import __version__
from thrsim.atomic import atomic_path, hdf5_in_memory
from thrsim.config import ReamingCaseConfig
from thrsim.errors import ThrsimInputError
from thrsim.provenance import config_hash

CHECKPOINT_FORMAT = "thrsim-checkpoint"
#: seconds of solving between two checkpoints of a case that checkpoints
CHECKPOINT_EVERY_S = 300.0
SUFFIX = ".resume"


def checkpoint_path(case_file: str | Path) -> Path:
    """Where the checkpoints of the case written to ``case_file`` go."""
    case_file = Path(case_file)
    return case_file.with_name(case_file.name + SUFFIX)


def _identity(case: ReamingCaseConfig) -> str:
    return config_hash(case.model_dump(mode="json"))


def write_checkpoint(path: Path, case: ReamingCaseConfig, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` (a snapshot of ``case``) to ``path`` atomically."""
    with atomic_path(path, suffix=".tmp") as tmp:
        with hdf5_in_memory(tmp) as f:
            f.attrs.update(format=CHECKPOINT_FORMAT, thrsim_version=__version__, config_hash=_identity(case))
            for name, values in arrays.items():
                f.create_dataset(name, data=np.asarray(values), compression="gzip", compression_opts=1)


def read_checkpoint(path: Path, case: ReamingCaseConfig) -> dict[str, np.ndarray] | None:
    """The snapshot in ``path`` when it is a checkpoint of this very case by this thrsim; None when it
    belongs to another case or version (it cannot be resumed); ThrsimInputError when it is unreadable."""
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != CHECKPOINT_FORMAT:
                raise ThrsimInputError(f"{path}: not a thrsim checkpoint")
            if f.attrs.get("thrsim_version") != __version__ or f.attrs.get("config_hash") != _identity(case):
                return None
            arrays: dict[str, np.ndarray] = {}
            f.visititems(lambda name, item: arrays.__setitem__(name, item[()]) if isinstance(item, h5py.Dataset) else None)
            return arrays
    except OSError as error:
        raise ThrsimInputError(f"{path}: an unreadable checkpoint ({error}); delete it to start the case afresh") from None


class Checkpointer:
    """Takes a checkpoint after a frame when ``every_s`` seconds have passed since the last one."""

    def __init__(self, path: Path, case: ReamingCaseConfig, snapshot, every_s: float):
        self.path, self.case, self.snapshot, self.every_s = path, case, snapshot, every_s
        self.last = time.monotonic()

    def __call__(self, frame: int) -> None:
        if time.monotonic() - self.last >= self.every_s:
            write_checkpoint(self.path, self.case, self.snapshot())
            self.last = time.monotonic()


def checkpointed_frames(path: Path) -> int | None:
    """How many frames the checkpoint at ``path`` holds (None: no readable checkpoint there)."""
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != CHECKPOINT_FORMAT:
                return None
            return int(f["run/scalars"][0])
    except (OSError, KeyError, ValueError):
        return None
