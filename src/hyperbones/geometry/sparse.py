"""Sparse matrices in the layout torch multiplies fastest."""

from __future__ import annotations

import warnings

import torch


def to_csr(matrix: torch.Tensor) -> torch.Tensor:
    """A COO matrix (duplicates summed) in CSR layout: the fast one for sparse @ dense
    (torch still calls it beta)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return matrix.coalesce().to_sparse_csr()


__all__ = ["to_csr"]
