"""The MeshGraphNet trunk shared by Module C (teacher) and Module B (canonical encoder).

Encode-process: node and edge features are embedded by MLPs, then ``num_blocks`` graph-net
blocks update every edge set from its two end nodes and every node from the sum of its
incoming edges, all with residual connections and LayerNorm (MeshGraphNets, as HOOD uses
them). Edge sets are named ("mesh", "world", ...); each has its own encoder and its own
edge MLP in every block.

Cost: the first layer of an edge MLP acts on [edge, sender, receiver]; it is split into
three matrices so that the sender/receiver parts are computed once per node and gathered,
not once per edge (the same function, half the edge work).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn


def mlp(in_features: int, out_features: int, hidden: int, layer_norm: bool = True) -> nn.Sequential:
    """Linear → ReLU → Linear (→ LayerNorm): (...,in) -> (...,out)."""
    layers: list[nn.Module] = [nn.Linear(in_features, hidden), nn.ReLU(), nn.Linear(hidden, out_features)]
    if layer_norm:
        layers.append(nn.LayerNorm(out_features))
    return nn.Sequential(*layers)


@dataclass
class EdgeSet:
    """Directed edges of one kind: senders (E,), receivers (E,) int64 node indices; features (E,Fe)."""

    senders: torch.Tensor
    receivers: torch.Tensor
    features: torch.Tensor


class _EdgeUpdate(nn.Module):
    """e' = e + MLP([e, h_sender, h_receiver]) with the first layer split per input."""

    def __init__(self, latent: int):
        super().__init__()
        self.from_edge = nn.Linear(latent, latent)
        self.from_sender = nn.Linear(latent, latent, bias=False)
        self.from_receiver = nn.Linear(latent, latent, bias=False)
        self.rest = nn.Sequential(nn.ReLU(), nn.Linear(latent, latent), nn.LayerNorm(latent))

    def forward(self, edges: torch.Tensor, nodes: torch.Tensor, senders: torch.Tensor,
                receivers: torch.Tensor) -> torch.Tensor:
        # index_select's backward is one index_add_, much cheaper on CPU than indexing's.
        hidden = (self.from_edge(edges) + self.from_sender(nodes).index_select(0, senders)
                  + self.from_receiver(nodes).index_select(0, receivers))
        return edges + self.rest(hidden)


class GraphNetBlock(nn.Module):
    """One message-passing step over nodes (N,L) and named edge sets (E_k,L)."""

    def __init__(self, latent: int, edge_sets: tuple[str, ...]):
        super().__init__()
        self.edge_sets = edge_sets
        self.edge_updates = nn.ModuleDict({name: _EdgeUpdate(latent) for name in edge_sets})
        self.node_update = mlp(latent * (1 + len(edge_sets)), latent, latent)

    def forward(self, nodes: torch.Tensor, edges: dict[str, torch.Tensor],
                topology: dict[str, tuple[torch.Tensor, torch.Tensor]]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        new_edges, incoming = {}, [nodes]
        for name in self.edge_sets:
            senders, receivers = topology[name]
            updated = self.edge_updates[name](edges[name], nodes, senders, receivers)
            new_edges[name] = updated
            incoming.append(torch.zeros_like(nodes).index_add_(0, receivers, updated))  # sum aggregation
        return nodes + self.node_update(torch.cat(incoming, dim=-1)), new_edges


class MeshGraphNet(nn.Module):
    """Encoder + ``num_blocks`` residual graph-net blocks -> node latents (N,latent).

    Args:
        node_features: width of the raw node features.
        edge_features: {edge set name: width of its raw features}.
        latent: latent width (paper: 128).
        num_blocks: message-passing blocks (paper: 15).
    """

    def __init__(self, node_features: int, edge_features: dict[str, int], latent: int = 128, num_blocks: int = 15):
        super().__init__()
        self.edge_set_names = tuple(edge_features)
        self.node_encoder = mlp(node_features, latent, latent)
        self.edge_encoders = nn.ModuleDict({name: mlp(width, latent, latent) for name, width in edge_features.items()})
        self.blocks = nn.ModuleList(GraphNetBlock(latent, self.edge_set_names) for _ in range(num_blocks))

    def forward(self, node_features: torch.Tensor, edge_sets: dict[str, EdgeSet]) -> torch.Tensor:
        """(N,Fn) node features and the named edge sets -> (N,latent) node latents."""
        nodes = self.node_encoder(node_features)
        edges = {name: self.edge_encoders[name](edge_sets[name].features) for name in self.edge_set_names}
        topology = {name: (edge_sets[name].senders, edge_sets[name].receivers) for name in self.edge_set_names}
        for block in self.blocks:
            nodes, edges = block(nodes, edges, topology)
        return nodes
