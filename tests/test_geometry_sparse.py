"""Sparse CSR matrices: duplicates summed, products as the dense matrix gives them, no beta warning."""

import warnings

import torch

from hyperbones.geometry.sparse import to_csr


def test_csr_sums_duplicates_and_multiplies_like_the_dense_matrix():
    indices = torch.tensor([[0, 0, 2, 1, 0], [1, 1, 0, 2, 3]])  # (0,1) twice
    values = torch.tensor([1.0, 2.0, -1.5, 4.0, 0.5])
    coo = torch.sparse_coo_tensor(indices, values, (3, 4), check_invariants=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # torch's "CSR support is in beta" warning would fail here
        matrix = to_csr(coo)
    assert matrix.layout == torch.sparse_csr
    dense = coo.to_dense()
    assert dense[0, 1] == 3.0
    x = torch.randn(4, 3, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(matrix @ x, dense @ x)
