"""Sparse Newton matrices for cloth: per-element Hessians by autograd (made positive
definite by taking their eigenvalues' absolute values) and their assembly into one sparse
matrix over the free coordinates, in a nested-dissection order that keeps sparse LU fill
small. Used by the canonical drape (``hyperbones.garment.drape``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sparse
import torch


def element_hessians(x: torch.Tensor, elements: torch.Tensor, energy) -> torch.Tensor:
    """(K,3n,3n) Hessians of ``energy(points, elements)`` for the K elements (K,n), each with
    its eigenvalues replaced by their absolute values. Autograd on an exploded copy where no
    two elements share a vertex: one Hessian-vector product per local coordinate gives that
    column of every element's Hessian."""
    count, size = elements.shape
    if count == 0:
        return x.new_zeros(0, 3 * size, 3 * size)
    exploded = x[elements].reshape(-1, 3).detach().requires_grad_(True)
    local = torch.arange(count * size, device=x.device).view(count, size)
    (gradient,) = torch.autograd.grad(energy(exploded, local), exploded, create_graph=True)
    hessians = x.new_zeros(count, 3 * size, 3 * size)
    probe = torch.zeros_like(exploded).view(count, 3 * size)
    for k in range(3 * size):
        probe.zero_()
        probe[:, k] = 1.0
        (column,) = torch.autograd.grad(gradient, exploded, probe.view(-1, 3), retain_graph=k < 3 * size - 1)
        hessians[:, :, k] = column.view(count, 3 * size)
    values, vectors = torch.linalg.eigh(0.5 * (hessians + hessians.transpose(1, 2)))
    return (vectors * values.abs()[:, None, :]) @ vectors.transpose(1, 2)


def dissection_order(positions: np.ndarray, adjacency: sparse.csr_matrix, leaf: int = 64) -> np.ndarray:
    """Geometric nested dissection of a mesh graph: split at the median of the longest axis
    and number both halves (recursively) before their separator (the vertices of one half
    with a neighbour in the other). Sparse LU in this order fills in about as much as with
    minimum degree but in dense blocks, and needs no ordering at each factorisation
    (timings: docs/experiments/*-drape-solver.md)."""
    order = []

    def dissect(nodes):
        if len(nodes) <= leaf:
            order.extend(nodes.tolist())
            return
        points = positions[nodes]
        axis = int(np.argmax(points.max(0) - points.min(0)))
        left = points[:, axis] < np.median(points[:, axis])
        separator = left & (adjacency[nodes][:, nodes] @ (~left).astype(float) > 0)
        dissect(nodes[left & ~separator])
        dissect(nodes[~left])
        order.extend(nodes[separator].tolist())

    dissect(np.arange(len(positions)))
    return np.asarray(order, dtype=np.int64)


class SparseHessian:
    """Sums per-element blocks (K,3n,3n) into a CSC matrix over the free vertices'
    coordinates, numbered in nested-dissection order; the sparsity pattern is found once."""

    def __init__(self, element_groups: list[torch.Tensor], free: torch.Tensor, positions: torch.Tensor):
        self.free_vertices = torch.nonzero(free).squeeze(-1)
        count = len(self.free_vertices)
        numbered = torch.full((len(free),), -1, dtype=torch.int64)
        numbered[self.free_vertices] = torch.arange(count)
        pairs = []
        for elements in element_groups:
            local = numbered[elements]
            a, b = (local[:, :, None].expand(-1, -1, local.shape[1]), local[:, None, :].expand(-1, local.shape[1], -1))
            kept = (a >= 0) & (b >= 0)
            pairs.append(torch.stack([a[kept], b[kept]]))
        pairs = torch.cat(pairs, 1).numpy()
        adjacency = sparse.csr_matrix((np.ones(pairs.shape[1]), (pairs[0], pairs[1])), shape=(count, count))
        self.in_order = torch.from_numpy(dissection_order(positions[self.free_vertices].numpy(), adjacency))
        rank = torch.empty(count, dtype=torch.int64)
        rank[self.in_order] = torch.arange(count)
        self.size = 3 * count
        self.index = torch.full((len(free), 3), -1, dtype=torch.int64)  # coordinate -> matrix row
        self.index[self.free_vertices] = 3 * rank[:, None] + torch.arange(3)
        self.index = self.index.view(-1)
        keys, self.kept = [], []
        for elements in element_groups + [torch.arange(len(free))[:, None]]:  # + diagonal blocks
            rows, columns, kept = self._pairs(elements)
            self.kept.append(kept)
            keys.append(columns[kept] * self.size + rows[kept])
        unique, self.scatter = torch.unique(torch.cat(keys), return_inverse=True)
        self.rows = (unique % self.size).numpy().astype(np.int32)
        per_column = np.bincount((unique // self.size).numpy(), minlength=self.size)
        self.column_starts = np.concatenate([[0], np.cumsum(per_column)]).astype(np.int32)

    def _pairs(self, elements: torch.Tensor):
        coordinates = self.index[(3 * elements[:, :, None] + torch.arange(3)).reshape(len(elements), -1)]
        rows = coordinates[:, :, None].expand(-1, -1, coordinates.shape[1])
        columns = coordinates[:, None, :].expand(-1, coordinates.shape[1], -1)
        return rows, columns, (rows >= 0) & (columns >= 0)

    def matrix(self, blocks: list[torch.Tensor]) -> sparse.csc_matrix:
        """The sum of the blocks (K,3n,3n) of each element group."""
        values = torch.cat([block[kept] for block, kept in zip(blocks, self.kept)]).double()
        data = torch.zeros(len(self.rows), dtype=torch.float64).index_add_(0, self.scatter[:len(values)], values)
        return sparse.csc_matrix((data.numpy(), self.rows, self.column_starts), shape=(self.size, self.size))

    def vertex_blocks(self, blocks: torch.Tensor) -> sparse.csc_matrix:
        """(V,3,3) per-vertex blocks as a block-diagonal matrix (pinned vertices left out)."""
        count = self.size // 3
        data = blocks[self.free_vertices[self.in_order]].double().numpy()
        return sparse.bsr_matrix((data, np.arange(count), np.arange(count + 1)), shape=(self.size, self.size)).tocsc()

    def to_free(self, vectors: torch.Tensor) -> np.ndarray:
        """(V,3) -> (size,) in the matrix's numbering."""
        kept = self.index >= 0
        out = np.zeros(self.size)
        out[self.index[kept].numpy()] = vectors.reshape(-1)[kept].double().numpy()
        return out

    def from_free(self, vector: np.ndarray) -> torch.Tensor:
        """(size,) -> (V,3), zero at pinned vertices."""
        kept = self.index >= 0
        out = torch.zeros(len(self.index), dtype=torch.float64)
        out[kept] = torch.from_numpy(vector)[self.index[kept]]
        return out.view(-1, 3)
