"""The learned simulator around the pure network: input normalisation, logits, α(t+1), the threshold.

Post-processing follows the thesis [7.3.3]: removed elements and halo nodes keep their α; every
other node gets α' = sigmoid(logit), the logit optionally added to logit(α_t) so that "nothing
changes" is the untrained default. The removal head (``ArchSettings.removal_head``) predicts the
probability p that an active element goes by t + 1 (α alone learns removal's expectation, which
never crosses the threshold under the teeth); the rollout adds the hazard −log(1 − p) per frame
and removes the element once the sum reaches ln 2. With damage the network also predicts D(t+1),
never below D(t). The reaction head (``ArchSettings.reaction_head``) gives each node a
non-negative share (softplus) of the next frame's axial reaction and torque, at no feed and per
unit of feed, weighted by :func:`~thrsim.learn.features.law_weights`: summed, the law R(v) = A + B·v
the feed balances the push against (:mod:`thrsim.learn.reaction_feed`): more push, never less feed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import torch
from torch import nn

from thrsim.learn.features import GraphBatch, input_widths
from thrsim.learn.network import GraphNetwork, NodeMLP
from thrsim.learn.settings import ModelSettings

_EPS = 1e-3

#: accumulated removal hazard at which an element goes: its survival probability is then 1/2
REMOVAL_HAZARD = math.log(2.0)


class Outputs(NamedTuple):
    """Per-node logits: α(t+1); removed at t+1 (removal head); D(t+1) (models with damage); the raw
    reaction and torque shares (reaction head)."""

    alpha: torch.Tensor
    removal: torch.Tensor | None
    damage: torch.Tensor | None
    reaction: torch.Tensor | None = None


class Prediction(NamedTuple):
    """Per node at t + 1: α, this step's removal hazard and D (None without damage); per subgraph,
    with the reaction head, the next frame's reaction law (A N, B N·s/m, A_T N·m, B_T N·m·s/m)."""

    alpha: torch.Tensor
    hazard: torch.Tensor
    damage: torch.Tensor | None
    reaction: torch.Tensor | None = None


#: reaction law columns: axial reaction at no feed (N) and per m/s; motor torque likewise (N·m)
REACTION_LAW = ("reaction_n", "reaction_n_s_m", "torque_n_m", "torque_n_m_s_m")
#: the feed one node's "per unit of feed" share is counted in (m/s), and the node count one
#: share is scaled by: an untrained head's law is then of the order of the training values
_FEED_UNIT_M_S, _NODES_UNIT = 1e-3, 1000.0
#: a recorded feed below this (m/s) with no element removed is a stall: the reaction then equals the
#: push, which says only that the law's reaction at no feed is at least as large (the push did not
#: overcome it); a slow feed that cuts is not (:func:`thrsim.learn.training.next_reaction`)
STALL_FEED_M_S = 2e-4


def balanced_feed_errors(law: torch.Tensor, recorded: torch.Tensor, scale_m_s: float) -> torch.Tensor:
    """The error of the feed at which the recorded push meets each law and the hold's damping
    (:func:`thrsim.learn.reaction_feed.feed_m_s`) against the recorded feed, on the scale
    log(1 + v / ``scale_m_s``) (``train.feed_loss_scale_mm_s``); ``recorded`` (n, 5) is (reaction, torque, feed, push, damping).
    A seated reamer's reaction meets the push within a newton or two, so a law fitted on its reaction
    alone can balance at a feed many times the solver's: this error is what the rollout's feed sees."""
    balanced = torch.clamp(recorded[:, 3] - law[:, 0], min=0.0) / (law[:, 1] + recorded[:, 4])
    return torch.log1p(balanced / scale_m_s) - torch.log1p(torch.clamp(recorded[:, 2], min=0.0) / scale_m_s)


def law_errors(law: torch.Tensor, recorded: torch.Tensor, scale: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The errors of reaction laws (n, 4) against the recorded (reaction N, torque N·m, feed m/s) (n, 3),
    in units of ``scale`` (reaction, torque): the law at the recorded feed less the record; at a stall
    (a recorded feed of 0 or less) a law's reaction above the record is no error (the push did not overcome it)."""
    feed = recorded[:, 2]
    force = (law[:, 0] + law[:, 1] * feed - recorded[:, 0]) / scale[0]
    force = torch.where(feed <= 0.0, torch.clamp(force, max=0.0), force)
    torque = (law[:, 2] + law[:, 3] * feed - recorded[:, 1]) / scale[1]
    return force, torque


class Normaliser(nn.Module):
    """Per-feature mean and standard deviation, fitted once on training inputs, then frozen."""

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, width: int):
        super().__init__()
        self.register_buffer("mean", torch.zeros(width))
        self.register_buffer("std", torch.ones(width))

    def fit(self, samples: torch.Tensor) -> None:
        self.mean.copy_(samples.mean(dim=0))
        # constant features (one-hots that never flip in the sample) are passed through centred
        self.std.copy_(samples.std(dim=0, unbiased=False).clamp_min(1e-8))
        self.std[self.std < 1e-6] = 1.0

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / self.std


class LearnedSimulator(nn.Module):
    """Normalisers + a network (``kind`` "gn": the Graph Network; "mlp": the node-wise baseline)."""

    reaction_scale: torch.Tensor

    def __init__(self, settings: ModelSettings, kind: str = "gn", threshold: float = 0.3):
        super().__init__()
        node_in, edge_in, global_in = input_widths(settings.features)
        self.kind = kind
        self.threshold = threshold
        self.residual_logit = settings.arch.residual_logit
        self.removal_head = settings.arch.removal_head
        self.damage = settings.features.damage
        self.reaction_head = settings.arch.reaction_head
        self.reaction_prior = settings.arch.reaction_prior
        self.feed_loss_weight = settings.train.feed_loss_weight
        self.feed_loss_scale_m_s = settings.train.feed_loss_scale_mm_s * 1e-3
        self.reaction_column = 1 + int(self.removal_head) + int(self.damage)
        outputs = self.reaction_column + 4 * int(self.reaction_head)
        if self.reaction_head:
            # the reaction's and torque's root mean square in training: the units the loss and the shares are in
            self.register_buffer("reaction_scale", torch.ones(2))
        self.node_norm = Normaliser(node_in)
        self.edge_norm = Normaliser(edge_in)
        self.global_norm = Normaliser(global_in)
        self.network: Callable[..., torch.Tensor]  # the GraphNetwork or NodeMLP; once compiled, its compiled form
        self.network_compiled = False
        if kind == "gn":
            self.network = GraphNetwork(node_in, edge_in, global_in, settings.arch, outputs)
        elif kind == "mlp":
            self.network = NodeMLP(node_in, global_in, settings.arch.mlp_baseline, outputs)
        else:
            raise ValueError(f"unknown network kind {kind!r}")

    def fit_normalisers(self, batch: GraphBatch) -> None:
        self.node_norm.fit(batch.nodes)
        self.edge_norm.fit(batch.edges)
        self.global_norm.fit(batch.globals_)
        if self.reaction_head:
            if batch.reaction is None:
                raise ValueError("a reaction head needs the cases' recorded reaction and torque")
            for column in range(2):
                values = batch.reaction[:, column]
                values = values[torch.isfinite(values)]
                self.reaction_scale[column] = float(values.square().mean().sqrt()) if len(values) and values.abs().max() > 0 else 1.0

    def normalised_inputs(self, batch: GraphBatch) -> tuple:
        """The network's arguments: normalised features and the graph's index tensors."""
        return (
            self.node_norm(batch.nodes),
            self.edge_norm(batch.edges),
            self.global_norm(batch.globals_),
            batch.senders,
            batch.receivers,
            batch.node_graph,
            batch.edge_graph,
        )

    def outputs(self, batch: GraphBatch) -> Outputs:
        """Per node: the logits of α(t+1), of p(removed at t+1) with the removal head, of D(t+1) with damage."""
        out = self.network(*self.normalised_inputs(batch))
        alpha_logit = out[:, 0]
        if self.residual_logit:
            alpha_logit = alpha_logit + _logit(batch.alpha)
        removal_logit = out[:, 1] if self.removal_head else None
        damage_logit = None
        if self.damage:
            damage_logit = out[:, 1 + int(self.removal_head)]
            if self.residual_logit:
                damage_logit = damage_logit + _logit(_damage(batch))
        return Outputs(alpha_logit, removal_logit, damage_logit, out[:, self.reaction_column :] if self.reaction_head else None)

    def reaction_law(self, batch: GraphBatch, shares: torch.Tensor) -> torch.Tensor:
        """(subgraphs, 4) reaction laws (see ``REACTION_LAW``) from the nodes' raw shares."""
        if batch.contact_weight is None:
            raise ValueError("a reaction head needs each node's contact weight")
        mask = self.trainable_mask(batch).to(shares.dtype)[:, None] * batch.contact_weight
        positive = nn.functional.softplus(shares) * mask / _NODES_UNIT
        sums = positive.new_zeros((batch.globals_.shape[0], 4)).index_add_(0, batch.node_graph, positive)
        force, torque = self.reaction_scale[0], self.reaction_scale[1]
        return sums * torch.stack([force, force / _FEED_UNIT_M_S, torque, torque / _FEED_UNIT_M_S])

    def loss(self, batch: GraphBatch, alpha_next: torch.Tensor, damage_next: torch.Tensor | None = None) -> torch.Tensor:
        """Cross-entropy on α(t+1) (eq. 49), plus, with the removal head, on removed-at-t+1 and,
        with damage, on D(t+1)."""
        mask = self.trainable_mask(batch)
        out = self.outputs(batch)
        loss = masked_bce(out.alpha, alpha_next, mask)
        if out.removal is not None:
            loss = loss + masked_bce(out.removal, (alpha_next < self.threshold).to(alpha_next.dtype), mask)
        if out.damage is not None:
            if damage_next is None:
                raise ValueError("a model with damage needs D(t+1) targets")
            loss = loss + masked_bce(out.damage, damage_next, mask)
        if out.reaction is not None:
            loss = loss + self._reaction_loss(batch, out.reaction)
        return loss

    def _reaction_loss(self, batch: GraphBatch, shares: torch.Tensor) -> torch.Tensor:
        """Squared error of the reaction and the torque at the recorded feed, in units of their root mean
        square; at a stall (a recorded feed of 0) only a reaction at no feed below the recorded one counts;
        plus, weighted by ``train.feed_loss_weight``, the squared :func:`balanced_feed_errors`."""
        if batch.reaction is None:
            raise ValueError("a model with a reaction head needs the next frame's reaction, torque and feed")
        law = self.reaction_law(batch, shares)
        known = torch.isfinite(batch.reaction[:, :3]).all(dim=1)
        if not bool(known.any()):
            return shares.sum() * 0.0
        force, torque = law_errors(law[known], batch.reaction[known], self.reaction_scale)
        loss = (force.square().mean() + torque.square().mean()) * 0.5
        if self.feed_loss_weight > 0.0:
            loss = (
                loss
                + self.feed_loss_weight * balanced_feed_errors(law[known], batch.reaction[known], self.feed_loss_scale_m_s).square().mean()
            )
        return loss

    def overshoot_loss(self, batch: GraphBatch) -> torch.Tensor:
        """Squared shortfall, in units of the reaction's root mean square, of each law's reaction at no feed
        below the push (``batch.reaction[:, 3]``), on states where the reamer sits deeper than the solver's
        in bone not yet cut: a rigid reamer cannot hold there under that push, so the balanced feed is 0."""
        shares = self.outputs(batch).reaction
        if batch.reaction is None or shares is None:
            raise ValueError("the overshoot loss needs a reaction head and each state's push")
        law = self.reaction_law(batch, shares)
        shortfall = torch.clamp(batch.reaction[:, 3] - law[:, 0], min=0.0) / self.reaction_scale[0]
        return shortfall.square().mean()

    def trainable_mask(self, batch: GraphBatch) -> torch.Tensor:
        """Nodes the loss sees and the model updates: in the region and active at t."""
        return batch.update & (batch.alpha >= self.threshold)

    @torch.no_grad()
    def predict(self, batch: GraphBatch) -> Prediction:
        """α at t + 1 on every batch node (unchanged where removed at t or outside the region), the
        removal hazard of this step (0 there, and everywhere without the removal head) and, with
        damage, D at t + 1 (at least D(t); unchanged where α is)."""
        mask = self.trainable_mask(batch)
        out = self.outputs(batch)
        alpha = torch.where(mask, torch.sigmoid(out.alpha), batch.alpha)
        hazard = (
            torch.zeros_like(alpha)
            if out.removal is None
            else torch.where(mask, nn.functional.softplus(out.removal), torch.zeros_like(alpha))
        )
        damage = None
        if out.damage is not None:
            damage = torch.where(mask, torch.maximum(torch.sigmoid(out.damage), _damage(batch)), _damage(batch))
        reaction = None if out.reaction is None else self.reaction_law(batch, out.reaction)
        return Prediction(alpha, hazard, damage, reaction)

    def alpha_next(self, batch: GraphBatch) -> torch.Tensor:
        """α at t + 1 alone (see :meth:`predict`)."""
        return self.predict(batch).alpha


def _logit(probability: torch.Tensor) -> torch.Tensor:
    return torch.logit(probability.clamp(_EPS, 1 - _EPS))


def _damage(batch: GraphBatch) -> torch.Tensor:
    """The batch's damage D(t), which a model that reads damage needs."""
    if batch.damage is None:
        raise ValueError("the model reads damage and the batch has none")
    return batch.damage


def masked_bce(logits: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Sigmoid cross-entropy on α(t+1) (eq. 49), averaged over the masked nodes only."""
    if not bool(mask.any()):
        return logits.sum() * 0.0
    return nn.functional.binary_cross_entropy_with_logits(logits[mask], target[mask])
