"""Smoothing of per-vertex values over a mesh's edges (Jacobi diffusion)."""

from __future__ import annotations

import torch


def diffusion_steps(length: float, edge_length: float, max_steps: int = 500) -> int:
    """Steps of ``diffuse`` that spread a value about ``length`` metres on edges of ``edge_length``
    (half-step Jacobi diffusion spreads about one edge length per sqrt(2 steps))."""
    return int(min(max_steps, max(1, 2 * (length / max(edge_length, 1e-4)) ** 2)))


def diffuse(values: torch.Tensor, edges: torch.Tensor, rate: torch.Tensor, steps: int) -> torch.Tensor:
    """Diffuse per-vertex ``values`` (V,C) over undirected ``edges`` (E,2) for ``steps`` Jacobi steps.

    rate: (V,1) in [0, 0.5], how much of its neighbours' mean each vertex takes per step
    (0: the vertex keeps its value).
    """
    num = values.shape[0]
    index = torch.cat([edges, edges.flip(1)]).T
    adjacency = torch.sparse_coo_tensor(index, torch.ones(index.shape[1], dtype=values.dtype, device=values.device),
                                        (num, num), check_invariants=False).coalesce()
    degree = torch.sparse.sum(adjacency, 1).to_dense().clamp(min=1)[:, None]
    for _ in range(steps):
        values = (1 - rate) * values + rate * torch.sparse.mm(adjacency, values) / degree
    return values
