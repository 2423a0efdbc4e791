"""The pure networks and the learned simulator's post-processing: shapes, permutations, masking."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from thrsim.learn.features import WIDTHS, GraphBatch, input_widths
from thrsim.learn.learned_simulator import LearnedSimulator, masked_bce
from thrsim.learn.network import GraphNetwork, NodeMLP
from thrsim.learn.settings import ArchSettings, ModelSettings, preset, thesis_arch


def _random_graph(n=30, m=90, seed=0, widths=WIDTHS["full"]):
    g = torch.Generator().manual_seed(seed)
    node_in, edge_in, global_in = widths
    return (
        torch.randn(n, node_in, generator=g),
        torch.randn(m, edge_in, generator=g),
        torch.randn(1, global_in, generator=g),
        torch.randint(0, n, (m,), generator=g),
        torch.randint(0, n, (m,), generator=g),
        torch.zeros(n, dtype=torch.long),
        torch.zeros(m, dtype=torch.long),
    )


@pytest.mark.parametrize("arch", [ArchSettings(), thesis_arch()], ids=["production", "thesis"])
@pytest.mark.parametrize("outputs", [1, 2])
def test_outputs_logits_per_node(arch, outputs):
    torch.manual_seed(0)
    net = GraphNetwork(*WIDTHS["full"], arch, outputs)
    assert net(*_random_graph()).shape == (30, outputs)
    assert NodeMLP(WIDTHS["full"][0], WIDTHS["full"][2], arch.mlp_baseline, outputs)(*_random_graph()).shape == (30, outputs)


def test_thesis_sizes_are_the_thesis_layers():
    arch = thesis_arch()
    assert (arch.node_encoder, arch.node_core, arch.node_decoder) == ((40,), (300, 300), (40,))
    assert (arch.edge_encoder, arch.edge_core) == ((20, 20), (30,))
    assert (arch.global_encoder, arch.global_core) == ((11, 11), (20,))
    assert arch.global_block and preset("thesis").features.feature_set == "thesis"


@pytest.mark.parametrize("arch", [ArchSettings(), thesis_arch()], ids=["production", "thesis"])
def test_outputs_follow_a_permutation_of_nodes_and_edges(arch):
    torch.manual_seed(1)
    net = GraphNetwork(*WIDTHS["full"], arch).double()
    nodes, edges, globals_, s, r, ng, eg = _random_graph()
    nodes, edges, globals_ = nodes.double(), edges.double(), globals_.double()
    out = net(nodes, edges, globals_, s, r, ng, eg)
    perm = torch.randperm(30, generator=torch.Generator().manual_seed(2))
    inverse = torch.argsort(perm)
    eperm = torch.randperm(90, generator=torch.Generator().manual_seed(3))
    out_p = net(nodes[perm], edges[eperm], globals_, inverse[s[eperm]], inverse[r[eperm]], ng, eg)
    assert torch.allclose(out_p, out[perm], atol=1e-9)


def test_messages_travel_one_hop_per_step():
    arch = ArchSettings(message_passing_steps=2)
    torch.manual_seed(0)
    net = GraphNetwork(*WIDTHS["full"], arch).double()
    # a path graph 0-1-2-3-4, both directions
    s = torch.tensor([0, 1, 1, 2, 2, 3, 3, 4])
    r = torch.tensor([1, 0, 2, 1, 3, 2, 4, 3])
    nodes = torch.randn(5, WIDTHS["full"][0], dtype=torch.float64)
    edges = torch.randn(8, WIDTHS["full"][1], dtype=torch.float64)
    args = (
        edges,
        torch.randn(1, WIDTHS["full"][2], dtype=torch.float64),
        s,
        r,
        torch.zeros(5, dtype=torch.long),
        torch.zeros(8, dtype=torch.long),
    )
    base = net(nodes, *args)
    changed = nodes.clone()
    changed[0] += 1.0
    diff = (net(changed, *args) - base).abs().squeeze(-1)
    assert diff[1] > 0 and diff[2] > 0  # within two hops
    assert diff[3] == 0 and diff[4] == 0  # beyond


def _batch(n=20, alpha=None, node_in=WIDTHS["full"][0]):
    _, edge_in, global_in = WIDTHS["full"]
    g = torch.Generator().manual_seed(5)
    s = torch.arange(n - 1)
    return GraphBatch(
        nodes=torch.randn(n, node_in, generator=g),
        edges=torch.randn(2 * (n - 1), edge_in, generator=g),
        globals_=torch.randn(1, global_in, generator=g),
        senders=torch.cat([s, s + 1]),
        receivers=torch.cat([s + 1, s]),
        node_graph=torch.zeros(n, dtype=torch.long),
        edge_graph=torch.zeros(2 * (n - 1), dtype=torch.long),
        alpha=alpha if alpha is not None else torch.rand(n, generator=g),
        update=torch.arange(n) < n - 4,
    )


def test_removed_and_halo_nodes_keep_their_alpha():
    torch.manual_seed(0)
    model = LearnedSimulator(ModelSettings(), "gn")
    alpha = torch.linspace(0.0, 1.0, 20)
    b = _batch(alpha=alpha)
    out = model.alpha_next(b)
    keep = ~b.update | (alpha < 0.3)
    assert torch.equal(out[keep], alpha[keep])
    assert not torch.equal(out[~keep], alpha[~keep])


def test_residual_logit_makes_an_untrained_output_layer_predict_no_change():
    model = LearnedSimulator(ModelSettings(), "gn")
    with torch.no_grad():
        model.network.output.weight.zero_()
        model.network.output.bias.zero_()
    alpha = torch.linspace(0.35, 0.95, 20)
    out = model.alpha_next(_batch(alpha=alpha))
    assert torch.allclose(out, alpha, atol=1e-6)


def _removal_model(removal_bias: float, damage_bias: float = 0.0) -> LearnedSimulator:
    """A production model whose outputs are constant: α logit 0 (α' = α_t), a fixed removal logit and
    a fixed damage logit increment (0: D' = D_t)."""
    model = LearnedSimulator(preset("production"), "gn")
    with torch.no_grad():
        model.network.output.weight.zero_()
        model.network.output.bias.copy_(torch.tensor([0.0, removal_bias, damage_bias]))
    return model


def _damaged_batch(alpha: torch.Tensor, damage: torch.Tensor) -> GraphBatch:
    b = _batch(alpha=alpha, node_in=input_widths(preset("production").features)[0])
    b.damage = damage
    return b


def test_removal_hazard_is_minus_log_survival_and_only_where_alpha_is_updated():
    assert preset("production").arch.removal_head and not ArchSettings().removal_head
    p = 0.2
    model = _removal_model(float(np.log(p / (1 - p))))
    alpha = torch.linspace(0.0, 1.0, 20)
    b = _damaged_batch(alpha, torch.rand(20))
    prediction = model.predict(b)
    out, hazard, damage = prediction.alpha, prediction.hazard, prediction.damage
    updated = b.update & (alpha >= 0.3)
    assert torch.allclose(hazard[updated], torch.full((int(updated.sum()),), -np.log(1 - p), dtype=torch.float32), rtol=1e-5)
    assert torch.all(hazard[~updated] == 0)
    assert torch.allclose(out, alpha, atol=1e-6)
    assert torch.allclose(damage, b.damage, atol=1e-6)


def test_the_removal_head_and_damage_add_their_cross_entropies():
    model = _removal_model(0.0)
    alpha = torch.linspace(0.35, 0.95, 20)
    b = _damaged_batch(alpha, torch.linspace(0.0, 0.9, 20))
    target = torch.where(torch.arange(20) % 2 == 0, torch.tensor(0.0), alpha)
    damage_next = (b.damage + 0.05).clamp(max=1.0)
    out = model.outputs(b)
    mask = model.trainable_mask(b)
    alpha_only = masked_bce(out.alpha, target, mask)
    expected = alpha_only + masked_bce(out.removal, (target < 0.3).float(), mask) + masked_bce(out.damage, damage_next, mask)
    assert torch.allclose(model.loss(b, target, damage_next), expected)
    assert float(model.loss(b, target, damage_next).detach()) > float(alpha_only.detach())
    with pytest.raises(ValueError, match="D\\(t\\+1\\)"):
        model.loss(b, target)


def test_predicted_damage_never_falls_and_changes_only_where_alpha_is_updated():
    alpha = torch.linspace(0.0, 1.0, 20)
    damage = torch.linspace(0.05, 0.95, 20)
    updated = _damaged_batch(alpha, damage).update & (alpha >= 0.3)
    falling = _removal_model(-50.0, damage_bias=-8.0).predict(_damaged_batch(alpha, damage)).damage
    assert torch.allclose(falling, damage)  # sigmoid below D(t) everywhere: D is kept
    rising = _removal_model(-50.0, damage_bias=2.0).predict(_damaged_batch(alpha, damage)).damage
    assert torch.all(rising[updated] > damage[updated]) and torch.all(rising[updated] <= 1.0)
    assert torch.equal(rising[~updated], damage[~updated])


def test_loss_sees_only_masked_nodes():
    logits = torch.randn(10, requires_grad=True)
    target = torch.rand(10)
    mask = torch.tensor([True, False] * 5)
    loss = masked_bce(logits, target, mask)
    loss.backward()
    assert torch.all(logits.grad[~mask] == 0) and torch.all(logits.grad[mask] != 0)
    other = logits.detach().clone()
    other[~mask] = 100.0
    assert torch.allclose(masked_bce(other, target, mask), loss)
    expected = torch.nn.functional.binary_cross_entropy_with_logits(logits[mask], target[mask])
    assert torch.allclose(loss, expected)
    assert float(masked_bce(logits, target, torch.zeros(10, dtype=torch.bool)).detach()) == 0.0


def test_normalisers_fit_then_centre_and_scale():
    model = LearnedSimulator(ModelSettings(), "gn")
    b = _batch()
    b.nodes = b.nodes * 1e-3 + 5.0
    model.fit_normalisers(b)
    normalised = model.node_norm(b.nodes)
    varying = b.nodes.std(dim=0) > 0
    assert torch.allclose(normalised.mean(dim=0), torch.zeros(normalised.shape[1]), atol=1e-3)
    assert np.allclose(normalised.std(dim=0, unbiased=False)[varying].numpy(), 1.0, atol=1e-3)
