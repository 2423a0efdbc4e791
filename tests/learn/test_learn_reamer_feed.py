"""The reamer's feed: the regressor's advance, and resting on the bone that is left."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from thrsim.data.synthetic import block_mesh
from thrsim.learn.advance import FEATURES, ArrayRegressor
from thrsim.learn.reamer_feed import ReamerFeed, advance_to_support

R = 22.9e-3
AXIS = np.array([0.0, 0.0, -1.0])


def _in_dome(points, centre):
    rel = points - centre
    return (np.linalg.norm(rel, axis=1) <= R * (1 + 1e-12)) & (rel @ AXIS >= -1e-15)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 30), st.integers(0, 2**31 - 1))
def test_advance_to_support_is_the_smallest_advance_that_brings_enough_nodes_into_the_dome(k, seed):
    rng = np.random.default_rng(seed)
    points = rng.uniform([-5e-3, -5e-3, -30e-3], [5e-3, 5e-3, -20e-3], (60, 3))
    centre = np.zeros(3)
    s = advance_to_support(points, centre, AXIS, R, k)
    assert 0.0 <= s < np.inf
    assert _in_dome(points, centre + s * AXIS).sum() >= k
    if s > 0:
        assert _in_dome(points, centre + (s - 1e-9) * AXIS).sum() < k


def test_points_behind_the_head_or_too_few_give_no_support():
    behind = np.array([[0.0, 0.0, 5e-3], [1e-3, 0.0, 1e-3]])
    assert advance_to_support(behind, np.zeros(3), AXIS, R, 1) == np.inf
    beside = np.array([[30e-3, 0.0, -1e-3]])  # off the axis beyond the teeth's reach
    assert advance_to_support(beside, np.zeros(3), AXIS, R, 1) == np.inf
    ahead = np.array([[0.0, 0.0, -25e-3]])
    assert np.isclose(advance_to_support(ahead, np.zeros(3), AXIS, R, 1), 25e-3 - R)
    assert advance_to_support(ahead, np.zeros(3), AXIS, R, 2) == np.inf


def _constant_regressor(advance_mm):
    width = len(FEATURES)
    return ArrayRegressor(
        "linear",
        {
            "mean": np.zeros(width),
            "scale": np.ones(width),
            "coef": np.zeros(width),
            "intercept": np.array(advance_mm),
            "target_range": np.array([0.0, 1.0]),
            "n_features": np.array(width),
        },
    )


def test_the_reamer_rests_on_the_remaining_bone_and_otherwise_follows_the_regressor():
    mesh = block_mesh(n=4)
    top = mesh.nodes[:, 2].max()
    centre = np.array([0.0, 0.0, top + R + 0.2e-3])  # teeth 0.2 mm above the block's top face
    alpha = np.full(mesh.n_tets, 0.58, dtype=np.float32)
    feed = ReamerFeed(_constant_regressor(0.01), mesh, R, 0.3, support_nodes=1)
    first = feed.advance_m(alpha, centre, centre, AXIS, 0.0, 0.0, 230.0, 0.0)
    assert feed.last_rested and np.isclose(first, 0.2e-3)
    touching = centre + first * AXIS
    assert np.isclose(feed.advance_m(alpha, touching, centre, AXIS, 0.0, 0.0, 230.0, 0.0), 0.01e-3)
    assert not feed.last_rested
    # remove the top layer under the reamer: it drops onto the next one
    upper = mesh.nodes[mesh.tets][:, :, 2].max(axis=1) >= top - 1e-12
    alpha[upper] = 0.0
    dropped = feed.advance_m(alpha, touching, centre, AXIS, 0.0, 0.0, 230.0, 0.0)
    assert feed.last_rested and dropped > 0.01e-3
    next_top = mesh.nodes[mesh.tets[~upper]][:, :, 2].max()
    assert np.isclose(dropped, top - next_top)
    # nothing left: no support, the regressor's advance stands
    alpha[:] = 0.0
    assert np.isclose(feed.advance_m(alpha, touching, centre, AXIS, 0.0, 0.0, 230.0, 0.0), 0.01e-3)
