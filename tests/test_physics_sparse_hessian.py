"""Sparse Newton matrices: element Hessians against autograd, assembly, the ordering."""

import numpy as np
import scipy.sparse as sparse
import torch

from hyperbones.physics.sparse_hessian import SparseHessian, dissection_order, element_hessians


def _grid(n: int = 6):
    """An n×n vertex grid in the z = 0 plane, (V,3) float64, and its (F,3) triangles."""
    u, v = torch.meshgrid(torch.arange(n, dtype=torch.float64), torch.arange(n, dtype=torch.float64), indexing="ij")
    points = torch.stack([u.reshape(-1), v.reshape(-1), torch.zeros(n * n, dtype=torch.float64)], -1) * 0.01
    ids = torch.arange(n * n).view(n, n)
    a, b, c, d = ids[:-1, :-1].reshape(-1), ids[1:, :-1].reshape(-1), ids[1:, 1:].reshape(-1), ids[:-1, 1:].reshape(-1)
    return points, torch.cat([torch.stack([a, b, c], -1), torch.stack([a, c, d], -1)])


def _springs(points, faces):
    """A convex quadratic per triangle: the squared lengths of its three edge vectors."""
    corners = points[faces]
    return (corners - corners.roll(1, dims=1)).square().sum()


def test_assembled_matrix_is_the_hessian_over_free_coordinates():
    points, faces = _grid()
    points = points + 0.002 * torch.randn_like(points)
    free = torch.ones(len(points), dtype=torch.bool)
    free[:6] = False  # one pinned row
    hessian = SparseHessian([faces], free, points)
    matrix = hessian.matrix([element_hessians(points, faces, _springs)]).toarray()
    dense = torch.autograd.functional.hessian(lambda x: _springs(x.view(-1, 3), faces), points.reshape(-1))
    keep = free.repeat_interleave(3)
    expected = dense[keep][:, keep].numpy()
    probe = torch.randn(len(points), 3, dtype=torch.float64)
    # Compare through products, since the matrix is numbered in dissection order.
    product = hessian.from_free(matrix @ hessian.to_free(probe))
    assert np.allclose(product.reshape(-1)[keep].numpy(), expected @ probe.reshape(-1)[keep].numpy())
    assert torch.equal(product[~free], torch.zeros(6, 3, dtype=torch.float64))
    assert np.allclose(matrix, matrix.T)


def test_element_hessians_are_positive_semidefinite():
    """A compressed triangle under a non-convex energy still gets a PSD block, of the same size."""
    points = torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.5, 0.0]], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2]])

    def buckling(x, elements):  # (|e|² − 1)² per edge: concave for short edges
        corners = x[elements]
        return ((corners - corners.roll(1, dims=1)).square().sum(-1) - 1.0).square().sum()

    block = element_hessians(points, faces, buckling)[0]
    exact = torch.autograd.functional.hessian(lambda x: buckling(x.view(-1, 3), faces), points.reshape(-1))
    assert float(torch.linalg.eigvalsh(exact).min()) < 0
    values = torch.linalg.eigvalsh(block)
    assert float(values.min()) > -1e-9
    assert torch.allclose(values.abs().sort().values, torch.linalg.eigvalsh(exact).abs().sort().values)


def test_dissection_order_is_a_permutation_with_separators_last():
    points, faces = _grid(12)
    pairs = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).numpy()
    adjacency = sparse.csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(144, 144))
    adjacency = adjacency + adjacency.T
    order = dissection_order(points.numpy(), adjacency, leaf=16)
    assert sorted(order.tolist()) == list(range(144))
    # The last vertices numbered are the top-level separator: removing them splits the grid.
    first_split = points.numpy()[order[-12:]]
    assert np.ptp(first_split[:, 0]) < 1e-9 or np.ptp(first_split[:, 1]) < 1e-9
