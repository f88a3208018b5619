"""Encode-process-decode graph network (pure learning: no units, walls or materials here).

Encoder MLPs lift node and edge features to latents; M interaction steps with unshared
weights update edges from (sender, receiver, edge) and nodes from (node, sum of incoming
messages), both with residuals; a decoder MLP reads the output per node. Every MLP has
`hidden_layers` hidden layers of `hidden` units with ReLU, and a LayerNorm on its output
except the decoder's.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.utils.checkpoint import checkpoint

EDGE_BLOCK = 16384  # edges per block in inference (16384 x 128 floats = 8 MiB per temporary)


def mlp(n_in: int, hidden: int, hidden_layers: int, n_out: int, layer_norm: bool = True) -> nn.Sequential:
    widths = [n_in] + [hidden] * hidden_layers
    layers: list[nn.Module] = []
    for a, b in zip(widths[:-1], widths[1:]):
        layers += [nn.Linear(a, b), nn.ReLU(inplace=True)]  # in place: no new [E, hidden] buffer
    layers.append(nn.Linear(widths[-1], n_out))
    if layer_norm:
        layers.append(nn.LayerNorm(n_out))
    return nn.Sequential(*layers)


class EdgeUpdate(nn.Module):
    """phi_e(v_s, v_r, e) with its first layer split (PhysicsNeMo's "concat trick"):
    W [v_s, v_r, e] + b = (W_s v + b)[s] + (W_r v)[r] + W_e e, so the node parts are
    projected once per node and gathered per edge instead of multiplying an [E, 3L] concat."""

    def __init__(self, latent: int, hidden: int, hidden_layers: int):
        super().__init__()
        self.project_nodes = nn.Linear(latent, 2 * hidden)  # [W_s | W_r], bias b
        self.project_edges = nn.Linear(latent, hidden, bias=False)  # W_e
        self.rest = nn.Sequential(nn.ReLU(inplace=True), *mlp(hidden, hidden, hidden_layers - 1, latent))

    def forward(self, v: torch.Tensor, e: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor):
        return self.messages(self.project_nodes(v), e, senders, receivers)

    def messages(self, projected: torch.Tensor, e: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor):
        """Messages [E, latent] from the node projections [N, 2 hidden] and edge latents."""
        from_sender, from_receiver = projected.chunk(2, dim=1)
        first = from_sender.index_select(0, senders).add_(from_receiver.index_select(0, receivers))
        first.addmm_(e.to(first.dtype), self.project_edges.weight.t().to(first.dtype))
        return self.rest(first)


class InteractionStep(nn.Module):
    def __init__(self, latent: int, hidden: int, hidden_layers: int):
        super().__init__()
        self.edge_update = EdgeUpdate(latent, hidden, hidden_layers)
        self.node_update = mlp(2 * latent, hidden, hidden_layers, latent)

    def forward(self, v, e, senders, receivers):
        if torch.is_grad_enabled():
            message = self.edge_update(v, e, senders, receivers)
            incoming = torch.zeros_like(v).index_add_(0, receivers, message.to(v.dtype))  # sum aggregation
            e = e + message
        else:
            incoming = self._messages_in_place(v, e, senders, receivers)
        v = v + self.node_update(torch.cat([v, incoming], dim=1))
        return v, e

    def _messages_in_place(self, v, e, senders, receivers):
        """Inference: edges in blocks of EDGE_BLOCK rows, each block's temporaries small
        enough to stay in cache and in the allocator (no page faults), e updated in place."""
        incoming = torch.zeros_like(v)
        projected = self.edge_update.project_nodes(v)
        for k in range(0, len(senders), EDGE_BLOCK):
            block = slice(k, k + EDGE_BLOCK)
            message = self.edge_update.messages(projected, e[block], senders[block], receivers[block])
            incoming.index_add_(0, receivers[block], message.to(v.dtype))
            e[block] += message
        return incoming


class EncodeProcessDecode(nn.Module):
    def __init__(
        self, node_in: int, edge_in: int, n_out: int,
        latent: int = 128, hidden: int = 128, hidden_layers: int = 2, steps: int = 10,
    ):
        super().__init__()
        self.node_encoder = mlp(node_in, hidden, hidden_layers, latent)
        self.edge_encoder = mlp(edge_in, hidden, hidden_layers, latent)
        self.processor = nn.ModuleList(InteractionStep(latent, hidden, hidden_layers) for _ in range(steps))
        self.decoder = mlp(latent, hidden, hidden_layers, n_out, layer_norm=False)

    def forward(self, nodes: torch.Tensor, edges: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor,
                recompute_steps: bool = False):
        """recompute_steps: recompute each processor step in backward (less memory in training)."""
        v = self.node_encoder(nodes)
        e = self.edge_encoder(edges)
        for step in self.processor:
            if recompute_steps and torch.is_grad_enabled():
                v, e = checkpoint(step, v, e, senders, receivers, use_reentrant=False)
            else:
                v, e = step(v, e, senders, receivers)
        return self.decoder(v)

    def widen_node_input(self, extra: int) -> None:
        """Append `extra` zero input columns to the node encoder, so the widened network
        computes exactly what it computed before for any values in the new columns."""
        old = self.node_encoder[0]
        new = nn.Linear(old.in_features + extra, old.out_features, device=old.weight.device, dtype=old.weight.dtype)
        with torch.no_grad():
            new.weight.zero_()
            new.weight[:, : old.in_features] = old.weight
            new.bias.copy_(old.bias)
        self.node_encoder[0] = new
