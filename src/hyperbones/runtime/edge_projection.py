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
every solve. Two solvers give the same answer: on the CPU a sparse LU factor (scipy), on a GPU
the matrix's dense inverse (one product per solve, shared by every garment of that topology),
so the whole projection stays in torch there. Measurements behind the defaults:
``docs/experiments/*-runtime-contact-projection.md``.
"""

from __future__ import annotations

import numpy as np
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.sparse import to_csr
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
                 compression: float = RuntimeConfig.projection_compression, solver: str = "auto",
                 device: str | torch.device = "cpu", compiled: bool = True):
        """iterations: local/global steps per ``project``; anchor: α; stretch, compression: the
        band of edge lengths left alone, as fractions of the rest length (0, 0: every edge is
        pulled to its rest length; the teacher's limiter uses ``physics.strain_limit``'s band).
        solver: "sparse" (scipy's LU, minimum-degree ordering, single precision: the fastest
        measured on a CPU; positions on any device are solved on the CPU), "dense" (the inverse
        in torch on ``device``: no host round trip, for GPUs) or "auto" (dense on CUDA).
        compiled: the sparse solver's iterations (local step, the LU factors' triangular
        solves, the planes) as compiled passes where numba imports (``runtime.projection_local``;
        the same numbers to float32 rounding), else numpy and SuperLU's solve."""
        import scipy.sparse  # here, so that importing this module stays light
        import scipy.sparse.linalg

        from hyperbones.physics.cloth import ClothRest

        if iterations < 1 or anchor <= 0:
            raise ParameterError(f"edge projection needs iterations >= 1 and anchor > 0, got {iterations}, {anchor}")
        if solver not in SOLVERS:
            raise ParameterError(f"edge projection solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
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
        lengths = rest.edge_lengths.numpy().astype(np.float32)
        self.low, self.high = lengths * (1.0 - compression), lengths * (1.0 + stretch)
        self.anchor, self.iterations = anchor, iterations
        self.device = torch.device(device)
        if solver == "auto":
            solver = "dense" if self.device.type == "cuda" else "sparse"
        self.solver = solver
        self._compiled = _compiled_steps() if compiled and solver == "sparse" else None
        self._first = np.ascontiguousarray(edges[:, 0], dtype=np.int64)
        self._second = np.ascontiguousarray(edges[:, 1], dtype=np.int64)
        if solver == "sparse":
            # Pivots on the diagonal (the matrix is diagonally dominant, so none is refused): the
            # row and column orders are one, and U = D Lᵀ, which the compiled solve relies on.
            factor = scipy.sparse.linalg.splu(system.tocsc(), permc_spec="MMD_AT_PLUS_A",
                                              options={"SymmetricMode": True, "DiagPivotThresh": 0.0})
            self.solve = factor.solve
            if self._compiled is not None:
                self._factors = _symmetric_factors(factor)
        else:
            self.inverse = _dense_inverse(system, edges, anchor, self.device)  # (V,V)
            self.difference_t = _sparse_csr(self.difference, self.device)  # (E,V)
            self.gather_t = _sparse_csr(self.gather, self.device)  # (V,E)
            self.low_t = torch.from_numpy(self.low).to(self.device)
            self.high_t = torch.from_numpy(self.high).to(self.device)

    def project(self, positions: torch.Tensor, contact=None) -> torch.Tensor:
        """(V,3) -> (V,3) after ``iterations`` local/global steps; ``contact`` (a
        ``ContactPlanes``) is enforced after each."""
        if self.solver == "dense":
            return self._project_dense(positions, contact)
        device, dtype = positions.device, positions.dtype
        world = positions.detach().cpu().double()
        # Solved about the garment's centre: single precision keeps 10x more of a 10 cm
        # offset than of a 1 m position (a rigidly moved garment comes back within 1e-5 m).
        centre = world.mean(0)
        x = (world - centre).float().numpy()
        planes = None
        if contact is not None and len(contact.vertex):  # the planes, moved with the origin
            contact = contact.to("cpu")
            vertex = contact.vertex.numpy()
            planes = (vertex, (contact.point.double() - centre).float().numpy(), contact.normal.float().numpy())
        target = self.anchor * x  # α a: the pull towards the input positions
        if self._compiled is not None:
            return (torch.from_numpy(self._project_compiled(x, target, planes)).double() + centre).to(
                device=device, dtype=dtype)
        # SuperLU solves column-major right-hand sides in place of copying them (~20 % of a solve).
        rhs = np.empty(x.shape, np.float32, order="F")
        one_each = planes is not None and _one_plane_a_vertex(planes[0])
        for _ in range(self.iterations):
            along = self.difference @ x
            length = np.sqrt(np.einsum("ij,ij->i", along, along)).clip(1e-12)
            wanted = along * (np.clip(length, self.low, self.high) / length)[:, None]
            rhs[:] = self.gather @ wanted + target
            x = self.solve(rhs)
            if planes is not None:
                x = _onto_planes(x, *planes, one_each)
        return (torch.from_numpy(x).double() + centre).to(device=device, dtype=dtype)

    def _project_compiled(self, x: np.ndarray, target: np.ndarray, planes) -> np.ndarray:
        """The sparse solver's iterations as compiled passes (``runtime.projection_local``): the
        local step and right-hand side, both triangular solves with SuperLU's factors, the
        planes. (V,3) float32 positions about the centre (overwritten: the answer is written into
        them) and α times them -> the projected (V,3)."""
        right_hand_side, ldl_solve, onto_planes = self._compiled
        rhs, work = np.empty_like(x), np.empty_like(x)
        push = None if planes is None else np.empty((len(planes[0]), 3), np.float32)
        for _ in range(self.iterations):
            right_hand_side(x, self._first, self._second, self.low, self.high, target, rhs)
            ldl_solve(rhs, *self._factors, work, x)
            if planes is not None:
                onto_planes(x, planes[0], planes[1], planes[2], push)
        return x

    def _project_dense(self, positions: torch.Tensor, contact=None) -> torch.Tensor:
        """``project`` in torch on the solver's device (the dense solver)."""
        dtype = positions.dtype
        world = positions.detach().to(self.device, torch.float64)
        centre = world.mean(0)
        x = (world - centre).float()
        if contact is not None:
            contact = contact.to(self.device)
            contact = ContactPlanes(contact.vertex, (contact.point.double() - centre).float(), contact.normal.float())
        target = self.anchor * x
        for _ in range(self.iterations):
            along = self.difference_t @ x
            length = along.norm(dim=1).clamp_min(1e-12)
            wanted = along * (torch.minimum(torch.maximum(length, self.low_t), self.high_t) / length)[:, None]
            x = self.inverse @ (self.gather_t @ wanted + target)
            if contact is not None:
                x = contact.project(x)
        return (x.double() + centre).to(device=positions.device, dtype=dtype)


SOLVERS = ("auto", "sparse", "dense")


def _compiled_steps():
    """``runtime.projection_local``'s right_hand_side, ldl_solve and onto_planes where numba
    imports, else None (numpy and SuperLU's solve then)."""
    try:
        from hyperbones.runtime.projection_local import ldl_solve, onto_planes, right_hand_side
    except ImportError:
        return None
    return right_hand_side, ldl_solve, onto_planes


def _symmetric_factors(factor) -> tuple[np.ndarray, ...]:
    """SuperLU's factorisation of a symmetric matrix with diagonal pivots (``P A Pᵀ = L U``,
    U = D Lᵀ) as the arrays ``projection_local.ldl_solve`` reads: perm (int32), L's strict lower
    part as CSC column starts, rows (sorted, int32) and float32 values, and 1/D (float32)."""
    import scipy.sparse

    if not np.array_equal(factor.perm_r, factor.perm_c):
        raise RuntimeError("edge projection: SuperLU pivoted off the diagonal, so its factor is not L D Lᵀ")
    lower = scipy.sparse.tril(factor.L, k=-1, format="csc")
    lower.sort_indices()
    as_index = lambda array: np.ascontiguousarray(array, dtype=np.int32)  # noqa: E731
    return (as_index(factor.perm_r), as_index(lower.indptr), as_index(lower.indices),
            np.ascontiguousarray(lower.data, dtype=np.float32),
            np.ascontiguousarray(1.0 / factor.U.diagonal(), dtype=np.float32))


_INVERSES: dict = {}  # (device, edges' bytes, anchor) -> the dense inverse, shared by garments of one topology


def _dense_inverse(system, edges: np.ndarray, anchor: float, device: torch.device) -> torch.Tensor:
    """The (V,V) float32 inverse of the sparse SPD ``system`` (DᵀD + anchor·I of the (E,2)
    ``edges``) on ``device`` (Cholesky in double precision there), cached by topology and anchor."""
    key = (str(device), edges.tobytes(), float(anchor), system.shape[0])
    if key not in _INVERSES:
        dense = torch.from_numpy(system.toarray()).to(device=device, dtype=torch.float64)
        _INVERSES[key] = torch.cholesky_inverse(torch.linalg.cholesky(dense)).float()
    return _INVERSES[key]


def _sparse_csr(matrix, device: torch.device) -> torch.Tensor:
    """A scipy sparse matrix as a torch sparse CSR tensor on ``device``."""
    coo = matrix.tocoo()
    indices = torch.from_numpy(np.stack([coo.row, coo.col]).astype(np.int64))
    return to_csr(torch.sparse_coo_tensor(indices, torch.from_numpy(coo.data), coo.shape,
                                          check_invariants=True)).to(device)


def _one_plane_a_vertex(vertex: np.ndarray) -> bool:
    """Whether the (C,) constrained vertices rise strictly (the runtime's planes: one per nearest face)."""
    return len(vertex) < 2 or bool((vertex[1:] > vertex[:-1]).all())


def _onto_planes(x: np.ndarray, vertex: np.ndarray, point: np.ndarray, normal: np.ndarray,
                 one_each: bool | None = None) -> np.ndarray:
    """``ContactPlanes.project`` in numpy: (V,3) positions with each constrained vertex (C,)
    behind its plane (point (C,3), unit normal (C,3)) moved onto it; a vertex with several
    planes gets the sum of their corrections, as there. one_each: ``_one_plane_a_vertex(vertex)``,
    when the caller knows it (the projection's planes stay the same over its iterations)."""
    gap = np.einsum("ij,ij->i", x[vertex] - point, normal)
    push = np.maximum(-gap, 0.0)[:, None] * normal  # (C,3)
    if one_each if one_each is not None else _one_plane_a_vertex(vertex):
        # One plane a vertex (the runtime's: one per nearest face, in vertex order): added in
        # place, the same numbers as the sum below at a fifth of its cost.
        out = x.copy()
        out[vertex] += push
        return out
    count = x.shape[0]
    correction = np.stack([np.bincount(vertex, weights=push[:, k], minlength=count) for k in range(3)], axis=1)
    return x + correction.astype(x.dtype)
