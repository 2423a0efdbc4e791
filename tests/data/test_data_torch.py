"""PyTorch readers: (t, t + h) pairs per split, streamed from the case files."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from thrsim.data.case_file import read_case
from thrsim.data.generate import load_dataset, run_sweep
from thrsim.data.labels import alpha
from thrsim.data.sweep import plan_sweep
from thrsim.data.torch_dataset import FramePairs, StreamingFramePairs


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds")
    plan = plan_sweep((0.0, 30.0), (0.0, 45.0, 90.0), frames=4, extra_forces_n=())
    run_sweep(root, plan, solver="synthetic", workers=1)
    return root


def test_map_style_pairs(dataset):
    train = FramePairs(dataset, split="train")
    assert [e["case_id"] for e in train.entries] == ["g000.0_t000.0_f230N", "g030.0_t000.0_f230N"]
    assert len(train) == 2 * 3
    sample = train[4]  # second case, t = 1
    assert sample["case_id"] == "g030.0_t000.0_f230N" and sample["t"] == 1
    case = read_case(train.entries[1]["path"])
    f = case.frames
    np.testing.assert_array_equal(sample["alpha"].numpy(), alpha(f.peeq[1], f.von_mises[1], f.status[1]))
    np.testing.assert_array_equal(sample["alpha_next"].numpy(), alpha(f.peeq[2], f.von_mises[2], f.status[2]))
    np.testing.assert_array_equal(sample["status_next"].numpy(), f.status[2])
    assert sample["alpha"].dtype == torch.float32 and sample["force_n"] == 230.0
    assert (sample["alpha_next"][sample["status_next"] == 0] == 0).all()
    assert train[-1]["t"] == 2
    with pytest.raises(IndexError):
        train[len(train)]
    assert len(FramePairs(dataset, split="test")) == 3 and len(FramePairs(dataset, split="validation")) == 3
    assert len(FramePairs(dataset, split=None, horizon=3)) == 4
    assert train.mesh(1).n_tets == case.mesh.n_tets
    batch = next(iter(DataLoader(train, batch_size=3)))
    assert batch["alpha"].shape == (3, case.mesh.n_tets)
    train.close()


def test_streaming_pairs(dataset):
    stream = StreamingFramePairs(dataset, split="train", shuffle=True, seed=3)
    first = [(s["case_id"], s["t"]) for s in stream]
    assert len(first) == len(stream) == 6 and len(set(first)) == 6
    assert first == [(s["case_id"], s["t"]) for s in stream]  # same epoch, same order
    stream.set_epoch(1)
    assert sorted(first) == sorted((s["case_id"], s["t"]) for s in stream)
    plain = [(s["case_id"], s["t"]) for s in StreamingFramePairs(dataset, split="test")]
    assert plain == [("g030.0_t045.0_f230N", t) for t in range(3)]
    assert all(e["split"] == "test" for e in load_dataset(dataset, split="test"))
