"""The reaming page's binary bone frames: exact round trips, compactness, malformed frames refused."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thrsim.app import bone_stream
from thrsim.errors import ThrsimInputError


@settings(max_examples=60, deadline=None)
@given(
    n_elements=st.integers(1, 200_000),
    changed_fraction=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**31 - 1),
)
def test_a_viewer_ends_up_with_exactly_the_current_levels(n_elements, changed_fraction, seed):
    rng = np.random.default_rng(seed)
    sent = rng.integers(0, 33, n_elements).astype(np.uint8)
    current = sent.copy()
    changed = rng.random(n_elements) < changed_fraction
    current[changed] = rng.integers(0, 33, int(changed.sum())).astype(np.uint8)
    message = bone_stream.update(12, sent, current)
    if np.array_equal(sent, current):
        assert message is None
        return
    frame, received = bone_stream.apply(message, sent)
    assert frame == 12 and np.array_equal(received, current)
    assert bone_stream.apply(bone_stream.update(13, None, current), None)[1].tolist() == current.tolist()


def test_ids_far_apart_round_trip():
    """Gaps of one to five varint bytes, the last element of a mesh above 2**16 included."""
    n = 2**21
    sent = np.zeros(n, dtype=np.uint8)
    current = sent.copy()
    ids = np.array([0, 1, 129, 130 + 2**14, 2**20, n - 1])
    current[ids] = [1, 2, 3, 4, 5, 6]
    message = bone_stream.update(1, sent, current)
    assert message[:1] == b"D"
    assert np.array_equal(bone_stream.apply(message, sent)[1], current)


def test_a_reaming_like_delta_is_a_few_percent_of_float32_alpha():
    """~10 % of 20,000 elements change, in runs of neighbouring ids, by a level or two."""
    rng = np.random.default_rng(3)
    n = 20_000
    sent = rng.integers(1, 33, n).astype(np.uint8)
    current = sent.copy()
    ids = np.unique(np.concatenate([start + np.arange(40) for start in rng.choice(n - 40, 50, replace=False)]))
    current[ids] = np.clip(sent[ids].astype(int) + rng.choice([-2, -1, 1, 2], len(ids)), 1, 32)
    message = bone_stream.update(2, sent, current)
    assert message[:1] == b"D"
    assert len(message) < 0.05 * 4 * n
    assert len(message) < 2 * len(ids)  # below a u16 id + u8 level (3 bytes) per change


@pytest.mark.parametrize(
    "message, match",
    [
        (b"D\x00", "shorter than its header"),
        (struct.pack("<cII", b"D", 1, 3) + b"not zlib", "not a zlib stream"),
        (struct.pack("<cII", b"K", 1, 5) + zlib.compress(b"\x01\x02"), "keyframe of 5 elements carries 2"),
        (struct.pack("<cII", b"D", 1, 3) + zlib.compress(b"\x00\x00"), "carries 2 ids"),
        (struct.pack("<cII", b"D", 1, 1) + zlib.compress(b"\x00\x07\x07"), "carries 2 levels"),
        (struct.pack("<cII", b"D", 1, 1) + zlib.compress(b"\x80\x80\x80\x80\x80\x01\x01"), "longer than 32 bits"),
        (struct.pack("<cII", b"D", 1, 1) + zlib.compress(b"\x09\x01"), "names element 9 of a mesh of 4"),
        (struct.pack("<cII", b"X", 1, 0) + zlib.compress(b""), "unexpected bone frame"),
    ],
)
def test_malformed_frames_are_refused_in_one_line(message, match):
    with pytest.raises(ThrsimInputError, match=match):
        bone_stream.apply(message, np.zeros(4, dtype=np.uint8))


def test_a_delta_before_any_keyframe_is_refused():
    message = bone_stream.update(1, np.zeros(4, np.uint8), np.array([0, 1, 0, 0], np.uint8))
    with pytest.raises(ThrsimInputError, match="before a keyframe"):
        bone_stream.apply(message, None)
