"""The network compiled for interactive use: ``torch.compile`` (TorchInductor's C++ backend).

Eager PyTorch runs each message-passing step as a chain of separate kernels, each a pass over the
region's edges or nodes; at a latent width of 32 those passes, not the arithmetic, set the time,
and Inductor fuses each chain into one C++ loop (speed: the docs' Learned simulator page,
compiled network). Shapes are symbolic (``dynamic=True``): the region changes size every frame
and must not trigger a recompile, nor may a tiny region (:class:`_WithSpareGraph`). Compiling
takes seconds and needs a C++ compiler, so it is opt-in, and any failure leaves the eager
network in place with the reason, never an error.
Inductor's cache goes to the user's cache folder (:func:`thrsim.cache.cache_dir`), not to
``/tmp/torchinductor_<user>``, a name another user can take first; TORCHINDUCTOR_CACHE_DIR wins.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import torch

from thrsim.cache import cache_dir
from thrsim.learn.features import GraphBatch
from thrsim.learn.learned_simulator import LearnedSimulator


def compile_network(model: LearnedSimulator, example: GraphBatch) -> str | None:
    """Compile ``model.network`` on ``example`` inputs, then swap it in; None on success, else a
    one-line reason (the eager network stays).

    The swap comes last, so another thread may go on stepping the eager network meanwhile (the
    trainer's server compiles in the background). The model is changed in place: every
    simulator sharing it then runs the compiled network.
    """
    if getattr(model, "network_compiled", False):
        return None
    if not os.environ.get("TORCHINDUCTOR_CACHE_DIR"):  # Inductor reads it when it compiles
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(cache_dir("inductor"))
    compiled = _WithSpareGraph(torch.compile(model.network, dynamic=True))
    try:
        with torch.inference_mode():  # as the step calls it: another grad mode would compile again
            compiled(*model.normalised_inputs(example))
    except Exception as error:  # noqa: BLE001 — any compiler failure means: stay eager
        first = str(error).strip().splitlines()
        return f"{type(error).__name__}: {first[0] if first else 'no message'}"
    model.network = compiled
    model.network_compiled = True
    return None


class _WithSpareGraph(torch.nn.Module):
    """The compiled network run on its batch plus a spare graph (two nodes joined both ways), whose
    rows are dropped.

    Inductor specialises sizes of 0 and 1 and an empty tensor's strides, so a region of one element,
    or one with no edges, compiled the network again inside a session: ticks of 1.6-11 s. With the
    spare graph no size falls under two and there are always two graphs. Graphs are independent
    (messages and global sums stay within each), so the batch's own rows are unchanged in value.
    """

    def __init__(self, compiled: Callable[..., torch.Tensor]):
        super().__init__()
        self.compiled = compiled

    def forward(self, nodes, edges, globals_, senders, receivers, node_graph, edge_graph) -> torch.Tensor:
        n_nodes, n_graphs = nodes.shape[0], globals_.shape[0]
        pair = torch.tensor([n_nodes, n_nodes + 1], dtype=senders.dtype)
        out = self.compiled(
            torch.cat([nodes, nodes.new_zeros((2, nodes.shape[1]))]),
            torch.cat([edges, edges.new_zeros((2, edges.shape[1]))]),
            torch.cat([globals_, globals_.new_zeros((1, globals_.shape[1]))]),
            torch.cat([senders, pair]),
            torch.cat([receivers, pair.flip(0)]),
            torch.cat([node_graph, node_graph.new_full((2,), n_graphs)]),
            torch.cat([edge_graph, edge_graph.new_full((2,), n_graphs)]),
        )
        return out[:n_nodes]
