"""How far a socket model's reamer moves under the surgeon's push: the push against the bone's reaction and the hold.

The solver's hand-held reamer is an effective mass on an axial damper (``ReamerHoldConfig``):
M·s̈ = F − R − c·ṡ. Over a frame the inertia term is small beside the others, so the frame's feed
is the v at which the push meets the bone's reaction law (:mod:`thrsim.learn.learned_simulator`,
R(v) = A + B·v, A and B ≥ 0) and the damper: v = max(0, F − A) / (B + c). Hence no push, no feed;
more push, never less feed; a reaction above the push stalls the reamer. In contact a balance below
the last advance is taken at once, one above it part way (the law depends on the advance it saw).
With nothing in contact (A = B = 0) the reamer closes in at F / c but stops where bone enters the
teeth and the network's cutting front sees it (the front finds elements by centroid, so a coarse
element can touch the teeth before the front holds it: stopping at the touch would leave no law).
"""

from __future__ import annotations

import math

import numpy as np

from thrsim.config import ReamerHoldConfig
from thrsim.learn.graph import StaticGraph, attached_nodes
from thrsim.learn.reamer_feed import advance_to_support

#: how far past the point where the first element enters the front's reach a reamer closing in stops (1 µm: inside, not on, the boundary)
FRONT_ENTRY_M = 1e-6

#: the share of a higher balance a frame in contact takes, the rest its last advance (see ReactionFeed.advance_m)
FEED_RELAXATION = 0.5


def feed_m_s(law: np.ndarray, force_n: float, damping_n_s_m: float) -> float:
    """The feed (m/s) at which ``force_n`` meets the reaction law (A, B, …) and the hold's damping."""
    reaction_n, per_feed = float(law[0]), float(law[1])
    return max(0.0, force_n - reaction_n) / (per_feed + damping_n_s_m)


def felt_at_push(law: np.ndarray, force_n: float, damping_n_s_m: float) -> tuple[float, float]:
    """The reaction (N) and motor torque (N·m) under ``force_n``, at the feed v it balances
    (:func:`feed_m_s`): the hold's balance F − c·v, which is the law's A + B·v while the reamer
    cuts and the whole push while it stalls (the bone takes no more than is pushed), and the law's torque."""
    feed = feed_m_s(law, force_n, damping_n_s_m)
    return max(0.0, force_n - damping_n_s_m * feed), float(law[2] + law[3] * feed)


class ReactionFeed:
    """The advance of one autonomous frame of a socket model (see the module)."""

    def __init__(
        self, graph: StaticGraph, teeth_radius_m: float, reach_margin_m: float, threshold: float, frame_dt_s: float, hold: ReamerHoldConfig
    ):
        self.graph, self.tets, self.nodes = graph, np.asarray(graph.mesh.tets), np.asarray(graph.mesh.nodes)
        self.teeth_radius_m, self.reach_margin_m = teeth_radius_m, reach_margin_m
        self.threshold, self.frame_dt_s = threshold, frame_dt_s
        self.damping_n_s_m = hold.axial_damping_n_s_m

    def advance_m(
        self, law: np.ndarray | None, alpha: np.ndarray, centre: np.ndarray, axis: np.ndarray, force_n: float, last_advance_m: float = 0.0
    ) -> float:
        """Advance along ``axis`` (m) over the next frame under ``force_n``, given the reaction law the
        last step predicted (None or all zero: nothing in contact) after advancing ``last_advance_m``.

        In contact a balance below the last advance is taken at once: the hold's inertia is small
        over a frame, so a stiffer bone slows the reamer within it (coasting on would carry a seating
        reamer past the seat, where the teeth cut a layer the solver keeps). A balance above the last
        advance is approached part way (:data:`FEED_RELAXATION`): the law is read after the last
        frame's advance, and a network that saw none predicts a soft bone, so speeding up to its
        balance at once would swing between stalling and plunging."""
        if not force_n > 0.0:
            return 0.0
        if law is not None and (law[0] > 0.0 or law[1] > 0.0):
            balanced = feed_m_s(law, force_n, self.damping_n_s_m) * self.frame_dt_s
            relaxed = FEED_RELAXATION * balanced + (1.0 - FEED_RELAXATION) * max(last_advance_m, 0.0)
            return min(balanced, relaxed)
        free = force_n / self.damping_n_s_m * self.frame_dt_s
        active = alpha >= self.threshold
        attached = attached_nodes(self.tets, active, len(self.nodes))
        contact = advance_to_support(self.nodes[attached], centre, axis, self.teeth_radius_m, 1)
        if math.isinf(contact):
            return free
        seen = self.graph.front_entry_m(active, centre, axis, self.teeth_radius_m + self.reach_margin_m) + FRONT_ENTRY_M
        return min(free, max(contact, seen))
