"""One frame after another: the learned step, the geometric baseline, and rollouts from a ground-truth frame.

A step takes the bone state at t (:class:`BoneState`: α, the accumulated removal hazard and, for
models with damage, D per element), the reamer centre at t + 1 (given, or advanced by the
regressor), the axis and the force, and returns the state at t + 1. Only the region near the
reamer is evaluated (see :mod:`thrsim.learn.graph`); elements outside it keep their state, since
nothing reaches them. An element whose
hazard reaches ``REMOVAL_HAZARD`` is removed (α = 0, as the solver's deleted elements).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from thrsim.learn.features import GraphBatch, ReamerState, batch, frame_arrays, law_contact_mm2, law_weights, select_subgraph
from thrsim.learn.graph import StaticGraph, Subgraph
from thrsim.learn.learned_simulator import REMOVAL_HAZARD, LearnedSimulator
from thrsim.learn.reaction_feed import ReactionFeed
from thrsim.learn.reamer_feed import ReamerFeed
from thrsim.learn.settings import FeatureSettings


@dataclass
class BoneState:
    """Per element (float32): α, the accumulated removal hazard, and damage D (zeros for models without it)."""

    alpha: np.ndarray
    hazard: np.ndarray
    damage: np.ndarray

    @classmethod
    def start(cls, alpha: np.ndarray, damage: np.ndarray | None = None) -> BoneState:
        """A state with no hazard accumulated yet; ``damage`` None for undamaged bone."""
        alpha = np.array(alpha, dtype=np.float32, copy=True)
        damage = np.zeros_like(alpha) if damage is None else np.array(damage, dtype=np.float32, copy=True)
        return cls(alpha, np.zeros_like(alpha), damage)

    def copy(self) -> BoneState:
        return BoneState(self.alpha.copy(), self.hazard.copy(), self.damage.copy())


@dataclass
class StepInfo:
    region: int
    subgraph: int


class LearnedStep:
    """α(t) → α(t+1) with a trained :class:`LearnedSimulator` (Graph Network or node-wise MLP); a frame
    that removed anything then deletes the chips it cut free (:meth:`StaticGraph.chips`), as the solver."""

    def __init__(
        self,
        model: LearnedSimulator,
        graph: StaticGraph,
        features: FeatureSettings,
        teeth_radius_m: float,
        cutting_energy_j_m3: np.ndarray | None = None,
    ):
        """``cutting_energy_j_m3``: every element's u_c, which the socket feature set reads. A socket
        model cuts only while the reamer advances: standing or pulled back, the teeth find no
        uncut bone in their path (the solver's cut follows the feed), so its step keeps the bone. Any
        model's teeth neither pushed nor advancing press on nothing: the step keeps the bone."""
        self.model = model.eval()
        self.graph = graph
        self.features = features
        self.set_teeth_radius(teeth_radius_m)
        self.cutting_energy_j_m3 = cutting_energy_j_m3
        self.cuts_only_advancing = features.feature_set == "socket"
        #: the reaction law of the frame after the last step (reaction head), None before the first or without one
        self.reaction_law: np.ndarray | None = None
        #: the contact that law summed over (mm², :func:`~thrsim.learn.features.law_contact_mm2`), None with no law
        self.law_contact_mm2: float | None = None
        self.last = StepInfo(0, 0)

    def set_teeth_radius(self, teeth_radius_m: float) -> None:
        """Cut with another reamer size from the next step (a socket model reads the size)."""
        self.teeth_radius_m = teeth_radius_m

    def inputs(
        self, state: BoneState, centre: np.ndarray, axis: np.ndarray, force_n: float, advance_m: float, omega_rad_s: float
    ) -> tuple[Subgraph, GraphBatch | None]:
        """The region's subgraph and the network's inputs for it (None for an empty region: nothing to run)."""
        graph = self.graph
        active = state.alpha >= self.model.threshold
        sub = select_subgraph(graph, self.features, active, centre, self.teeth_radius_m)
        if sub.n_region == 0:
            return sub, None
        reamer = ReamerState(
            np.asarray(centre, dtype=np.float64),
            np.asarray(axis, dtype=np.float64),
            float(force_n),
            float(advance_m),
            float(omega_rad_s),
            self.teeth_radius_m,
        )
        alpha_sub = state.alpha[sub.nodes]
        damage_sub = state.damage[sub.nodes] if self.features.damage else None
        arrays = frame_arrays(
            graph,
            sub,
            alpha_sub,
            reamer,
            self.features.feature_set,
            self.model.threshold,
            active,
            damage_sub,
            self.features.corners,
            self.cutting_energy_j_m3,
        )
        weights = (
            [law_weights(graph, sub, reamer, self.cutting_energy_j_m3, self.model.reaction_prior)] if self.model.reaction_head else None
        )
        return sub, batch([(sub, alpha_sub, arrays)], None if damage_sub is None else [damage_sub], None, weights)

    def __call__(
        self, state: BoneState, centre: np.ndarray, axis: np.ndarray, force_n: float, advance_m: float, omega_rad_s: float
    ) -> BoneState:
        out = state.copy()
        sub, inputs = self.inputs(state, centre, axis, force_n, advance_m, omega_rad_s)
        self.last = StepInfo(sub.n_region, len(sub.nodes))
        if inputs is None:
            self.reaction_law = None if not self.model.reaction_head else np.zeros(4)
            self.law_contact_mm2 = None if not self.model.reaction_head else 0.0
            return out
        with torch.inference_mode():
            prediction = self.model.predict(inputs)
        if prediction.reaction is not None:
            self.reaction_law = prediction.reaction[0].numpy().astype(np.float64)
            self.law_contact_mm2 = law_contact_mm2(self.graph, sub)
        if not advance_m > 0.0 and (self.cuts_only_advancing or not force_n > 0.0):
            return out
        region, n = sub.region, sub.n_region
        out.alpha[region] = prediction.alpha[:n].numpy()
        out.hazard[region] += prediction.hazard[:n].numpy()
        if prediction.damage is not None:
            out.damage[region] = prediction.damage[:n].numpy()
        out.alpha[region[out.hazard[region] >= REMOVAL_HAZARD]] = 0.0
        removed_now = out.alpha[region] < self.model.threshold
        if (removed_now & (state.alpha[region] >= self.model.threshold)).any():  # a cut can leave a chip, as in the solver
            out.alpha[self.graph.chips(out.alpha >= self.model.threshold)] = 0.0
        return out


class GeometricStep:
    """Baseline: every element whose centroid enters the teeth's envelope (the dome in front of the
    head centre, radius of the teeth's reach) is removed; nothing else changes."""

    def __init__(self, graph: StaticGraph, teeth_radius_m: float):
        self.graph = graph
        self.teeth_radius_m = teeth_radius_m

    def __call__(
        self, state: BoneState, centre: np.ndarray, axis: np.ndarray, force_n: float, advance_m: float, omega_rad_s: float
    ) -> BoneState:
        rel = self.graph.centroids - centre
        inside = (np.einsum("ij,ij->i", rel, rel) < self.teeth_radius_m**2) & (rel @ axis >= 0.0)
        out = state.copy()
        out.alpha[inside] = 0.0
        return out


def rollout(
    step, case, start: int, frames: int, threshold: float, feed: ReamerFeed | ReactionFeed | None, push_n: float | None = None
) -> tuple[list[np.ndarray], np.ndarray]:
    """Run ``frames`` steps from the ground truth at ``start``; (removed masks at start+1 … start+frames, centres).

    With ``feed`` the reamer moves by itself (autonomous): by the regressor, resting on the bone
    (a patch model), or by the push against the reaction law the step predicts (a socket model,
    whose first law comes from a standing step at the start); without, it follows the recorded
    positions (tool-forced). ``push_n`` replaces the push the case was reamed with.
    """
    if isinstance(feed, ReactionFeed):
        return _pushed_rollout(step, case, start, frames, threshold, feed, case.recorded_push_n() if push_n is None else push_n)
    state = BoneState.start(case.alpha[start], None if case.damage is None else case.damage[start])
    centre = case.positions[start].copy()
    masks, centres = [], []
    push = case.force_n if push_n is None else push_n
    for k in range(1, frames + 1):
        if feed is None:
            new_centre = case.positions[start + k]
        else:
            impulse = push * case.frame_dt_s * (start + k - 1)
            new_centre = (
                centre
                + feed.advance_m(
                    state.alpha, centre, case.positions[0], case.axis, case.inclination_deg, case.anteversion_deg, push, impulse
                )
                * case.axis
            )
        moved = float((new_centre - centre) @ case.axis)
        state = step(state, new_centre, case.axis, push, moved, case.omega_rad_s)
        removed = state.alpha < threshold
        centre = new_centre
        masks.append(removed)
        centres.append(centre)
    return masks, np.array(centres)


def _pushed_rollout(step: LearnedStep, case, start: int, frames: int, threshold: float, feed: ReactionFeed, push_n: float):
    """A socket model's autonomous rollout: each frame's advance from the push and the last predicted law."""
    state = BoneState.start(case.alpha[start], None if case.damage is None else case.damage[start])
    centre = case.positions[start].copy()
    step(state, centre, case.axis, push_n, 0.0, case.omega_rad_s)  # standing: the bone's law, no cut
    masks, centres = [], []
    moved = 0.0
    for _ in range(frames):
        moved = feed.advance_m(step.reaction_law, state.alpha, centre, case.axis, push_n, moved)
        centre = centre + moved * case.axis
        state = step(state, centre, case.axis, push_n, moved, case.omega_rad_s)
        masks.append(state.alpha < threshold)
        centres.append(centre)
    return masks, np.array(centres)
