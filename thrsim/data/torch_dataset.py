"""PyTorch readers of a dataset: (frame t, frame t + h) pairs streamed from the case files.

Neither reader loads a whole case: each pair reads two frames (one HDF5 chunk per per-element
dataset and frame). Each sample is a dict of tensors::

    alpha, alpha_next        (E,) float32  α at t and t + h (eq. 47, 0 for removed elements)
    status, status_next      (E,) uint8
    peeq, von_mises          (E,) float32  at t
    reamer_position, reamer_position_next  (3,) float64 m
    reamer_axis              (3,) float64
    force_n, inclination_deg, anteversion_deg, t   scalars; case_id: str

The mesh of a case (centroids, adjacency) is static: get it once with :meth:`FramePairs.mesh`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from thrsim.config import LabelConfig
from thrsim.data.case_file import CaseReader
from thrsim.data.generate import load_dataset
from thrsim.data.labels import alpha


def _sample(reader: CaseReader, entry: dict, t: int, horizon: int, labels: LabelConfig) -> dict:
    a, b = reader.frame(t), reader.frame(t + horizon)
    return {
        "alpha": torch.from_numpy(alpha(a["peeq"], a["von_mises"], a["status"], labels)),
        "alpha_next": torch.from_numpy(alpha(b["peeq"], b["von_mises"], b["status"], labels)),
        "status": torch.from_numpy(np.asarray(a["status"])),
        "status_next": torch.from_numpy(np.asarray(b["status"])),
        "peeq": torch.from_numpy(np.asarray(a["peeq"])),
        "von_mises": torch.from_numpy(np.asarray(a["von_mises"])),
        "reamer_position": torch.from_numpy(np.asarray(a["reamer_position"])),
        "reamer_position_next": torch.from_numpy(np.asarray(b["reamer_position"])),
        "reamer_axis": torch.from_numpy(np.asarray(reader.reamer_axis)),
        "force_n": float(reader.attrs.get("force_n", 0.0)),
        "inclination_deg": float(reader.attrs.get("inclination_deg", 0.0)),
        "anteversion_deg": float(reader.attrs.get("anteversion_deg", 0.0)),
        "t": int(t),
        "case_id": entry["case_id"],
    }


class _Base:
    def __init__(self, root: str | os.PathLike, split: str | None = "train", horizon: int = 1, labels: LabelConfig | None = None):
        if horizon < 1:
            raise ValueError("horizon must be at least 1")
        self.root = Path(root)
        self.split = split
        self.horizon = horizon
        self.labels = labels or LabelConfig()
        self.entries = load_dataset(self.root, split=split)
        self.pairs_per_case = [max(0, int(e["frames"]) - horizon) for e in self.entries]

    def mesh(self, case_index: int = 0):
        with CaseReader(self.entries[case_index]["path"]) as reader:
            return reader.mesh


class FramePairs(_Base, Dataset):
    """Map-style: index → (case, t); files are opened lazily, one handle per case per process."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._offsets = np.concatenate([[0], np.cumsum(self.pairs_per_case)]).astype(np.int64)
        self._readers: dict[int, CaseReader] = {}
        self._pid = os.getpid()

    def __len__(self) -> int:
        return int(self._offsets[-1])

    def _reader(self, case: int) -> CaseReader:
        if os.getpid() != self._pid:  # a DataLoader worker: never share h5py handles across a fork
            self._readers, self._pid = {}, os.getpid()
        if case not in self._readers:
            self._readers[case] = CaseReader(self.entries[case]["path"])
        return self._readers[case]

    def __getitem__(self, index: int) -> dict:
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(index)
        case = int(np.searchsorted(self._offsets, index, side="right") - 1)
        t = int(index - self._offsets[case])
        return _sample(self._reader(case), self.entries[case], t, self.horizon, self.labels)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_readers"] = {}
        return state

    def close(self) -> None:
        for reader in self._readers.values():
            reader.close()
        self._readers = {}


class StreamingFramePairs(_Base, IterableDataset):
    """Iterable: streams every pair of every case once per epoch, one open case at a time.

    With ``shuffle`` the case order and the frame order within a case are permuted by a seed
    (plus the epoch set by :meth:`set_epoch`). DataLoader workers split the cases among them.
    """

    def __init__(self, *args, shuffle: bool = False, seed: int = 0, **kwargs):
        super().__init__(*args, **kwargs)
        self.shuffle = shuffle
        self.seed = seed
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return int(sum(self.pairs_per_case))

    def __iter__(self):
        rng = np.random.default_rng([self.seed, self.epoch])
        order = rng.permutation(len(self.entries)) if self.shuffle else np.arange(len(self.entries))
        info = get_worker_info()
        if info is not None:
            order = order[info.id :: info.num_workers]
        for case in order:
            entry = self.entries[int(case)]
            steps = np.arange(self.pairs_per_case[int(case)])
            if self.shuffle:
                steps = rng.permutation(steps)
            with CaseReader(entry["path"]) as reader:
                for t in steps:
                    yield _sample(reader, entry, int(t), self.horizon, self.labels)
