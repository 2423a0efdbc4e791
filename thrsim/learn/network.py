"""Pure networks: the encode–process–decode Graph Network [7.3.2] and the node-wise MLP baseline.

No I/O, no normalisation, no physics: tensors in, ``outputs`` logits per node out (N, outputs). Aggregation is a sum
over incoming edges (``index_add_``), so the output does not depend on the order of nodes or
edges. The first layer of every edge function is split into an edge part and per-node sender
and receiver projections, computed once per node and gathered per edge: the same function as a
layer on the concatenation, with the per-edge work of a single matrix product (the "concat
trick", worth it because a tet graph has ~4 directed edges per node).
"""

from __future__ import annotations

import torch
from torch import nn

from thrsim.learn.settings import ArchSettings


def mlp(in_size: int, sizes: tuple[int, ...], layer_norm: bool = False) -> tuple[nn.Module, int]:
    """Linear + ReLU for every listed width (identity for none), optional LayerNorm; (module, out width)."""
    layers: list[nn.Module] = []
    width = in_size
    for size in sizes:
        layers += [nn.Linear(width, size), nn.ReLU()]
        width = size
    if layer_norm and sizes:
        layers.append(nn.LayerNorm(width))
    return nn.Sequential(*layers), width


def _sum_by(index: torch.Tensor, values: torch.Tensor, count: int) -> torch.Tensor:
    out = values.new_zeros((count, values.shape[1]))
    return out.index_add_(0, index, values)


class _SplitFirstLayer(nn.Module):
    """``Linear([parts...])`` computed part by part; the first part carries the bias."""

    def __init__(self, sizes: tuple[int, ...], out: int):
        super().__init__()
        self.parts = nn.ModuleList([nn.Linear(size, out, bias=i == 0) for i, size in enumerate(sizes)])

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        total = self.parts[0](inputs[0])
        for layer, x in zip(self.parts[1:], inputs[1:], strict=True):
            total = total + layer(x)
        return total


class _Function(nn.Module):
    """An update function φ whose input is a concatenation of parts: split first layer, then an MLP."""

    def __init__(self, part_sizes: tuple[int, ...], sizes: tuple[int, ...], layer_norm: bool):
        super().__init__()
        if not sizes:
            raise ValueError("an update function needs at least one layer")
        self.first = _SplitFirstLayer(part_sizes, sizes[0])
        self.rest, self.out_size = mlp(sizes[0], sizes[1:], layer_norm)
        self.rest = nn.Sequential(nn.ReLU(), self.rest)

    def project(self, index: int, x: torch.Tensor) -> torch.Tensor:
        return self.first.parts[index](x)

    def finish(self, pre: torch.Tensor) -> torch.Tensor:
        return self.rest(pre)


class _Core(nn.Module):
    """One GN block [Battaglia et al. 2018]: edges, then nodes (sum of incoming edges), then globals."""

    def __init__(self, node_in: int, edge_in: int, global_in: int, arch: ArchSettings):
        super().__init__()
        self.global_block = arch.global_block
        g = global_in if arch.global_block else 0
        edge_parts = (edge_in, node_in, node_in) + ((g,) if g else ())
        self.edge = _Function(edge_parts, arch.edge_core, arch.layer_norm)
        node_parts = (node_in, self.edge.out_size) + ((g,) if g else ())
        self.node = _Function(node_parts, arch.node_core, arch.layer_norm)
        if arch.global_block:
            self.glob = _Function((global_in, self.node.out_size, self.edge.out_size), arch.global_core, arch.layer_norm)
            self.global_out = self.glob.out_size
        else:
            self.global_out = global_in
        self.node_out, self.edge_out = self.node.out_size, self.edge.out_size

    def forward(self, nodes, edges, globals_, senders, receivers, node_graph, edge_graph, n_graphs):
        pre = self.edge.project(0, edges)
        pre = pre + self.edge.project(1, nodes)[senders] + self.edge.project(2, nodes)[receivers]
        if self.global_block:
            pre = pre + self.edge.project(3, globals_)[edge_graph]
        new_edges = self.edge.finish(pre)
        incoming = _sum_by(receivers, new_edges, nodes.shape[0])
        pre = self.node.project(0, nodes) + self.node.project(1, incoming)
        if self.global_block:
            pre = pre + self.node.project(2, globals_)[node_graph]
        new_nodes = self.node.finish(pre)
        if self.global_block:
            node_sum = _sum_by(node_graph, new_nodes, n_graphs)
            edge_sum = _sum_by(edge_graph, new_edges, n_graphs)
            new_globals = self.glob.finish(self.glob.first(globals_, node_sum, edge_sum))
        else:
            new_globals = globals_
        return new_nodes, new_edges, new_globals


class GraphNetwork(nn.Module):
    """Encode–process–decode GN: k core steps on [encoded, latent], a linear output W (eq. 48).

    With ``residual`` the core's input is the latent itself and its output is added to it
    (MeshGraphNets); otherwise the thesis's graph_nets layout: the core reads the encoded graph
    concatenated with the current latent and replaces it.
    """

    def __init__(self, node_in: int, edge_in: int, global_in: int, arch: ArchSettings, outputs: int = 1):
        super().__init__()
        self.arch = arch
        node_in_total = node_in + (0 if arch.global_block else global_in)
        self.node_encoder, node_w = mlp(node_in_total, arch.node_encoder, arch.layer_norm)
        self.edge_encoder, edge_w = mlp(edge_in, arch.edge_encoder, arch.layer_norm)
        self.global_encoder, global_w = mlp(global_in, arch.global_encoder if arch.global_block else (), arch.layer_norm)
        if arch.residual:
            if arch.node_core[-1] != node_w or arch.edge_core[-1] != edge_w:
                raise ValueError("residual updates need the core's output widths equal to the encoders'")
            core_in = (node_w, edge_w, global_w)
        else:
            # the core reads [encoded, latent]; the latent starts at zero so every step, and a
            # shared core, sees the same input width
            out_g = arch.global_core[-1] if arch.global_block and arch.global_core else global_w
            core_in = (node_w + arch.node_core[-1], edge_w + arch.edge_core[-1], global_w + out_g)
        steps = 1 if arch.shared_core else arch.message_passing_steps
        cores = [_Core(*core_in, arch) for _ in range(steps)]
        self.cores = nn.ModuleList(cores)
        latent_node = cores[-1].node_out
        self.node_decoder, dec_w = mlp(latent_node, arch.node_decoder, False)
        self.output = nn.Linear(dec_w, outputs)

    def forward(self, nodes, edges, globals_, senders, receivers, node_graph, edge_graph) -> torch.Tensor:
        n_graphs = globals_.shape[0]
        if not self.arch.global_block:
            nodes = torch.cat([nodes, globals_[node_graph]], dim=1)
        enc_n, enc_e, enc_g = self.node_encoder(nodes), self.edge_encoder(edges), self.global_encoder(globals_)
        if self.arch.residual:
            lat_n, lat_e, lat_g = enc_n, enc_e, enc_g
        else:
            core = self.cores[0]
            lat_n = enc_n.new_zeros((enc_n.shape[0], core.node_out))
            lat_e = enc_e.new_zeros((enc_e.shape[0], core.edge_out))
            lat_g = enc_g.new_zeros((enc_g.shape[0], core.global_out if self.arch.global_block else 0))
        for step in range(self.arch.message_passing_steps):
            core = self.cores[0] if self.arch.shared_core else self.cores[step]
            if self.arch.residual:
                d_n, d_e, d_g = core(lat_n, lat_e, lat_g, senders, receivers, node_graph, edge_graph, n_graphs)
                lat_n, lat_e = lat_n + d_n, lat_e + d_e
                lat_g = lat_g + d_g if self.arch.global_block else lat_g
            else:
                lat_n, lat_e, new_g = core(
                    torch.cat([enc_n, lat_n], 1),
                    torch.cat([enc_e, lat_e], 1),
                    torch.cat([enc_g, lat_g], 1),
                    senders,
                    receivers,
                    node_graph,
                    edge_graph,
                    n_graphs,
                )
                lat_g = new_g if self.arch.global_block else lat_g
        return self.output(self.node_decoder(lat_n))


class NodeMLP(nn.Module):
    """The thesis's baseline [7.3.5]: the node core alone, applied to each node's features and the force."""

    def __init__(self, node_in: int, global_in: int, sizes: tuple[int, ...], outputs: int = 1):
        super().__init__()
        self.body, width = mlp(node_in + global_in, sizes)
        self.output = nn.Linear(width, outputs)

    def forward(self, nodes, edges, globals_, senders, receivers, node_graph, edge_graph) -> torch.Tensor:
        return self.output(self.body(torch.cat([nodes, globals_[node_graph]], dim=1)))
