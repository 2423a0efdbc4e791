"""The learned simulator around the pure network: input normalisation, logits, α(t+1), the threshold.

Post-processing follows the thesis [7.3.3]: elements removed at t (α < threshold) keep their α;
halo nodes (context only) keep theirs too; every other node gets α' = sigmoid(logit), with the
logit optionally added to logit(α_t) so that "nothing changes" is the untrained default.
"""

from __future__ import annotations

import torch
from torch import nn

from thrsim.learn.features import WIDTHS, GraphBatch
from thrsim.learn.network import GraphNetwork, NodeMLP
from thrsim.learn.settings import ModelSettings

_EPS = 1e-3


class Normaliser(nn.Module):
    """Per-feature mean and standard deviation, fitted once on training inputs, then frozen."""

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

    def __init__(self, settings: ModelSettings, kind: str = "gn", threshold: float = 0.3):
        super().__init__()
        node_in, edge_in, global_in = WIDTHS[settings.features.feature_set]
        self.kind = kind
        self.threshold = threshold
        self.residual_logit = settings.arch.residual_logit
        self.node_norm = Normaliser(node_in)
        self.edge_norm = Normaliser(edge_in)
        self.global_norm = Normaliser(global_in)
        if kind == "gn":
            self.network = GraphNetwork(node_in, edge_in, global_in, settings.arch)
        elif kind == "mlp":
            self.network = NodeMLP(node_in, global_in, settings.arch.mlp_baseline)
        else:
            raise ValueError(f"unknown network kind {kind!r}")

    def fit_normalisers(self, batch: GraphBatch) -> None:
        self.node_norm.fit(batch.nodes)
        self.edge_norm.fit(batch.edges)
        self.global_norm.fit(batch.globals_)

    def logits(self, batch: GraphBatch) -> torch.Tensor:
        out = self.network(
            self.node_norm(batch.nodes), self.edge_norm(batch.edges), self.global_norm(batch.globals_),
            batch.senders, batch.receivers, batch.node_graph, batch.edge_graph,
        )
        if self.residual_logit:
            out = out + torch.logit(batch.alpha.clamp(_EPS, 1 - _EPS))
        return out

    def trainable_mask(self, batch: GraphBatch) -> torch.Tensor:
        """Nodes the loss sees and the model updates: in the region and active at t."""
        return batch.update & (batch.alpha >= self.threshold)

    @torch.no_grad()
    def alpha_next(self, batch: GraphBatch) -> torch.Tensor:
        """α at t + 1 on every batch node (unchanged where removed at t or outside the region)."""
        predicted = torch.sigmoid(self.logits(batch))
        return torch.where(self.trainable_mask(batch), predicted, batch.alpha)


def masked_bce(logits: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Sigmoid cross-entropy on α(t+1) (eq. 49), averaged over the masked nodes only."""
    if not bool(mask.any()):
        return logits.sum() * 0.0
    return nn.functional.binary_cross_entropy_with_logits(logits[mask], target[mask])
