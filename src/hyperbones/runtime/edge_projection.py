"""Edge-length projection for the per-frame runtime: Module A's garment pulled back towards its
rest edge lengths while staying near where Module A put it (a projective-dynamics solve).

Module A blends rigid bone frames; where neighbouring bones move differently, the blend
stretches the cloth. A local, edge-by-edge fix (the teacher's Jacobi strain limiter) spreads a
correction one ring of vertices per sweep; here every iteration is global instead (Bouaziz et
al. 2014, "Projective Dynamics"):

    minimise  Σ_e |(x_i − x_j) − d_e|²  +  α Σ_v |x_v − a_v|²

with a the input positions and d_e the current edge vector scaled to its rest length l_e
(or clamped to a band around it). The local step sets every d_e at once; the global step is
one solve with the constant matrix DᵀD + αI (D: the (E,V) edge-difference matrix), factorised
once per garment. Contact half-spaces (``physics.contact_planes.ContactPlanes``) are enforced after
every solve. The solve runs on the CPU whatever the device of the positions. Measurements
behind the defaults: ``docs/experiments/*-runtime-contact-projection.md``.
"""

from __future__ import annotations

import numpy as np
import torch

from hyperbones.errors import ParameterError
from hyperbones.physics.contact_planes import ContactPlanes
from hyperbones.runtime.config import RuntimeConfig


class EdgeProjection:
    """The projection for one garment: (V,3) canonical vertices and (F,3) faces; ``project``
    takes (V,3) positions (any device) and returns them on that device.

    edges: (E,2) the garment's undirected edges; rest_lengths: (E,) m.
    """

    def __init__(self, rest_vertices: torch.Tensor, faces: torch.Tensor,
                 iterations: int = RuntimeConfig.projection_iterations, anchor: float = RuntimeConfig.projection_anchor,
                 stretch: float = RuntimeConfig.projection_stretch,
                 compression: float = RuntimeConfig.projection_compression):
        """iterations: local/global steps per ``project``; anchor: α; stretch, compression: the
        band of edge lengths left alone, as fractions of the rest length (0, 0: every edge is
        pulled to its rest length; the teacher's limiter uses ``physics.strain_limit``'s band).
        Factorised with a minimum-degree ordering in single precision (the fastest measured)."""
        import scipy.sparse  # here, so that importing this module stays light
        import scipy.sparse.linalg

        from hyperbones.physics.cloth import ClothRest

        if iterations < 1 or anchor <= 0:
            raise ParameterError(f"edge projection needs iterations >= 1 and anchor > 0, got {iterations}, {anchor}")
        if not (0.0 <= compression < 1.0 and stretch >= 0.0):
            raise ParameterError(f"edge projection needs 0 <= compression < 1 and stretch >= 0, got {compression}, "
                                 f"{stretch}")
        rest = ClothRest.from_mesh(rest_vertices.detach().cpu().double(), faces.cpu())
        self.edges, self.rest_lengths = rest.edges, rest.edge_lengths.float()
        edges = rest.edges.numpy()
        count, num_vertices = len(edges), rest_vertices.shape[0]
        rows = np.repeat(np.arange(count), 2)
        columns = edges[:, ::-1].reshape(-1)  # x[second] − x[first]
        signs = np.tile([1.0, -1.0], count)
        self.difference = scipy.sparse.csr_matrix((signs, (rows, columns)), shape=(count, num_vertices),
                                                  dtype=np.float32)
        self.gather = self.difference.T.tocsr()
        system = (self.gather @ self.difference + anchor * scipy.sparse.identity(num_vertices, dtype=np.float32))
        self.solve = scipy.sparse.linalg.splu(system.tocsc(), permc_spec="MMD_AT_PLUS_A",
                                              options={"SymmetricMode": True}).solve
        lengths = rest.edge_lengths.numpy().astype(np.float32)
        self.low, self.high = lengths * (1.0 - compression), lengths * (1.0 + stretch)
        self.anchor, self.iterations = anchor, iterations

    def project(self, positions: torch.Tensor, contact=None) -> torch.Tensor:
        """(V,3) -> (V,3) after ``iterations`` local/global steps; ``contact`` (a
        ``ContactPlanes``) is enforced after each."""
        device, dtype = positions.device, positions.dtype
        world = positions.detach().cpu().double()
        # Solved about the garment's centre: single precision keeps 10x more of a 10 cm
        # offset than of a 1 m position (a rigidly moved garment comes back within 1e-5 m).
        centre = world.mean(0)
        if contact is not None:  # the planes, moved with the origin
            contact = contact.to("cpu")
            contact = ContactPlanes(contact.vertex, (contact.point.double() - centre).float(), contact.normal.float())
        x = (world - centre).float().numpy()
        target = self.anchor * x
        for _ in range(self.iterations):
            along = self.difference @ x
            length = np.linalg.norm(along, axis=1).clip(1e-12)
            wanted = along * (np.clip(length, self.low, self.high) / length)[:, None]
            x = self.solve(self.gather @ wanted + target)
            if contact is not None:
                x = contact.project(torch.from_numpy(x)).numpy()
        return (torch.from_numpy(x).double() + centre).to(device=device, dtype=dtype)
