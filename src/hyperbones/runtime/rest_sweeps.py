"""Jacobi sweeps that pull every edge of a garment towards its rest length: what finishes a
garment after its proxy's correction is spread on it (``runtime.simulator``).

The proxy's projection fixes the stretch it can see, at its own scale; between its vertices
Module A's stretch is left. That stretch is short-range, which is what Jacobi sweeps remove
fastest: each sweep moves both ends of every edge towards its rest length, every vertex by the
mean of its edges' moves times ``relaxation`` (over-relaxed constraint averaging: 1 is the
teacher's strain limiter without its band; up to 2 converges in fewer sweeps and stays stable),
then keeps the skin planes. On the CPU the sweeps are one compiled loop where numba imports
(no band to branch on, fast-math: ~0.08 ms a sweep at 5k vertices, against ~0.23 for the
strain limiter's); elsewhere (the torch-only path, a GPU) two sparse products a sweep.
"""

from __future__ import annotations

import numpy as np
import torch

from hyperbones.geometry.sparse import to_csr
from hyperbones.physics.contact_planes import ContactPlanes


class RestLengthSweeps:
    """``sweeps`` Jacobi sweeps over a garment's (E,2) edges towards their (E,) rest lengths."""

    def __init__(self, edges: torch.Tensor, rest_lengths: torch.Tensor, num_vertices: int, sweeps: int,
                 relaxation: float = 1.0, device: str | torch.device = "cpu"):
        self.sweeps, self.relaxation = int(sweeps), float(relaxation)
        self.device = torch.device(device)
        self._compiled = _compiled_sweeps() if self.device.type == "cpu" else None
        edges = edges.to(torch.int64).cpu()
        degree = torch.bincount(edges.reshape(-1), minlength=num_vertices).clamp_min(1).float()
        # Each end takes half of its edge's move, averaged over the end's edges, times the relaxation.
        share_first = 0.5 * self.relaxation / degree[edges[:, 0]]
        share_second = -0.5 * self.relaxation / degree[edges[:, 1]]
        self._arrays = (edges[:, 0].numpy().copy(), edges[:, 1].numpy().copy(),
                        rest_lengths.detach().cpu().float().numpy().copy(), share_first.numpy(), share_second.numpy())
        count = edges.shape[0]
        index = torch.arange(count)
        ones = torch.ones(count)
        self.rest_lengths = rest_lengths.detach().float().to(self.device)
        self.difference = to_csr(torch.sparse_coo_tensor(  # (E,V): x[second] − x[first]
            torch.stack([index.repeat(2), torch.cat([edges[:, 1], edges[:, 0]])]), torch.cat([ones, -ones]),
            (count, num_vertices), check_invariants=True)).to(self.device)
        self.spread = to_csr(torch.sparse_coo_tensor(  # (V,E): each end's share of its edge's move
            torch.stack([torch.cat([edges[:, 0], edges[:, 1]]), index.repeat(2)]),
            torch.cat([share_first, share_second]), (num_vertices, count), check_invariants=True)).to(self.device)

    def project(self, positions: torch.Tensor, contact: ContactPlanes | None = None) -> torch.Tensor:
        """(V,3) -> (V,3) after the sweeps; ``contact``'s planes are kept after every sweep."""
        if self._compiled is not None and positions.device.type == "cpu" and positions.dtype == torch.float32:
            if contact is None or not len(contact.vertex):
                planes = (np.zeros(0, np.int64), np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32))
            else:
                planes = (contact.vertex.to(torch.int64).numpy(), contact.point.float().contiguous().numpy(),
                          contact.normal.float().contiguous().numpy())
            x = positions.detach().numpy().copy()
            self._compiled(x, *self._arrays, self.sweeps, *planes)
            return torch.from_numpy(x)
        x = positions
        for _ in range(self.sweeps):
            along = self.difference @ x
            squares = along * along
            length = squares.mv(squares.new_ones(3)).sqrt().clamp_min(1e-12)
            x = x + self.spread @ (((length - self.rest_lengths) / length)[:, None] * along)
            if contact is not None:
                x = contact.project(x)
        return x


def _compiled_sweeps():
    """``rest_sweeps_compiled.rest_length_sweeps`` where numba imports, else None (torch then)."""
    try:
        from hyperbones.runtime.rest_sweeps_compiled import rest_length_sweeps
    except ImportError:
        return None
    return rest_length_sweeps
