"""Strain limiting: a position-based projection that keeps every mesh edge within a band
around its rest length (Provot 1995's strain limiting, as position-based dynamics projects
edge constraints).

Woven cloth barely stretches: its stretching stiffness is orders of magnitude above its
bending stiffness, so an explicit or learnt integrator that gets the accelerations slightly
wrong leaves the cloth visibly elastic. A few projection sweeps after each step remove that
error at a fixed, small cost. Limiting the three edges of every triangle bounds its whole
metric, so shear is limited as well as stretch.

Each sweep measures all edges at once, moves both ends of every edge outside the band
towards the band's edge in proportion to their inverse masses (pinned vertices do not
move), and averages the corrections a vertex receives over its edges (Jacobi), so the
result does not depend on edge order and the loop runs over sweeps only. Both halves of a
sweep are one sparse product each (edge vectors from positions, vertex moves from edge
corrections). The averaging under-relaxes: ``LIMIT_ITERATIONS`` sweeps pull the bulk of the
error in without converging. Contact half-spaces (``physics.contact_planes.ContactPlanes``) are
enforced after every sweep, so the pull of the limit and the push out of the body settle
together. Sweep counts and the Gauss-Seidel variant that was rejected:
docs/experiments/*-teacher-strain-limiter.md.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field

import numpy as np
import torch

from hyperbones.geometry.sparse import to_csr
from hyperbones.physics.contact_planes import ContactPlanes

# The teacher's band: woven cloth stretches by a percent or so under its own weight and
# buckles rather than compresses in-plane.
STRETCH_LIMIT = 0.01  # an edge may grow to 1.01 l0
COMPRESSION_LIMIT = 0.03  # and shrink to 0.97 l0
LIMIT_ITERATIONS = 40


@dataclass
class StrainLimiter:
    """Projection of garment positions towards ``(1 - compression) l0 <= l <= (1 + stretch) l0``.

    edges: (E,2) vertex indices of each undirected edge; rest_lengths: (E,);
    inverse_masses: (V,) 1/kg, 0 for pinned vertices; edge_counts: (V,) edges per vertex.
    """

    edges: torch.Tensor
    rest_lengths: torch.Tensor
    inverse_masses: torch.Tensor
    edge_counts: torch.Tensor
    stretch: float = STRETCH_LIMIT
    compression: float = COMPRESSION_LIMIT
    iterations: int = LIMIT_ITERATIONS
    # Each vertex moves by this times the mean of its edges' corrections (1: plain averaging;
    # up to 2: over-relaxed, fewer sweeps to the same strain: the runtime's proxy sweeps).
    relaxation: float = 1.0
    # (E,V) sparse: edge vectors x[second] - x[first] = difference @ x.
    difference: torch.Tensor = field(init=False, repr=False)
    # (V,E) sparse: each vertex's averaged, mass-weighted share of its edges' corrections.
    spread: torch.Tensor = field(init=False, repr=False)
    # (E,) each end's share of its edge's correction (the second's negative): ``spread``'s values by edge.
    share_first: torch.Tensor = field(init=False, repr=False)
    share_second: torch.Tensor = field(init=False, repr=False)
    # The compiled sweeps' inputs as numpy arrays (ends, band, shares), made on their first use.
    _sweep_arrays: tuple | None = field(init=False, default=None, repr=False)

    def __post_init__(self):
        first, second = self.edges[:, 0], self.edges[:, 1]
        count, num_vertices = len(first), len(self.inverse_masses)
        w_first, w_second = self.inverse_masses[first], self.inverse_masses[second]
        w_sum = (w_first + w_second).clamp_min(1e-30)  # both pinned: both weights 0, nothing moves
        edge_index = torch.arange(count, device=first.device)
        ones = torch.ones(count, device=first.device)
        self.difference = to_csr(torch.sparse_coo_tensor(
            torch.stack([edge_index.repeat(2), torch.cat([second, first])]), torch.cat([ones, -ones]),
            (count, num_vertices), check_invariants=False))
        self.share_first = w_first / w_sum / self.edge_counts[first] * self.relaxation
        self.share_second = -w_second / w_sum / self.edge_counts[second] * self.relaxation
        shares = torch.cat([self.share_first, self.share_second])
        self.spread = to_csr(torch.sparse_coo_tensor(
            torch.stack([torch.cat([first, second]), edge_index.repeat(2)]), shares,
            (num_vertices, count), check_invariants=False))

    @classmethod
    def build(cls, edges: torch.Tensor, rest_lengths: torch.Tensor, masses: torch.Tensor, pinned_mask: torch.Tensor,
              stretch: float = STRETCH_LIMIT, compression: float = COMPRESSION_LIMIT,
              iterations: int = LIMIT_ITERATIONS, relaxation: float = 1.0) -> "StrainLimiter":
        """edges (E,2) unique undirected, rest_lengths (E,) m, masses (V,) kg, pinned_mask (V,) bool."""
        if not (stretch >= 0 and 0 <= compression < 1 and iterations >= 0 and 0 < relaxation <= 2):
            raise ValueError(f"strain limits need stretch >= 0, 0 <= compression < 1, iterations >= 0 and "
                             f"0 < relaxation <= 2; got {stretch}, {compression}, {iterations}, {relaxation}")
        inverse_masses = torch.where(pinned_mask, torch.zeros_like(masses), 1.0 / masses.clamp_min(1e-12))
        counts = torch.zeros(len(masses), dtype=torch.float32, device=masses.device)
        counts.index_add_(0, edges.reshape(-1), torch.ones(edges.numel(), device=counts.device))
        return cls(edges, rest_lengths.float(), inverse_masses.float(), counts.clamp_min(1.0),
                   float(stretch), float(compression), int(iterations), float(relaxation))

    @classmethod
    def for_cloth(cls, rest, pinned_mask: torch.Tensor) -> "StrainLimiter":
        """The teacher's limiter for a garment: a ``physics.cloth.ClothRest`` (its edges, rest
        lengths and vertex masses) and its (V,) pinned mask, with the module's band."""
        return cls.build(rest.edges, rest.edge_lengths, rest.vertex_masses, pinned_mask)

    def to(self, device: torch.device | str) -> "StrainLimiter":
        """The limiter on ``device``; itself when already there (its sparse matrices are built once)."""
        if self.edges.device == torch.device(device):
            return self
        return StrainLimiter(self.edges.to(device), self.rest_lengths.to(device), self.inverse_masses.to(device),
                             self.edge_counts.to(device), self.stretch, self.compression, self.iterations,
                             self.relaxation)

    def project(self, positions: torch.Tensor, contact: ContactPlanes | None = None) -> torch.Tensor:
        """(V,3) -> (V,3) positions after ``iterations`` Jacobi sweeps; ``contact`` (a
        ``physics.contact_planes.ContactPlanes``), when given, is enforced after every sweep.

        On the CPU without gradients the sweeps run compiled (``physics.strain_sweeps``, where
        numba is installed); elsewhere (a GPU, autograd) in torch. The two agree to float32
        rounding."""
        if _compiled_sweeps_apply(positions):
            return self._project_compiled(positions, contact)
        low, high = self.rest_lengths * (1.0 - self.compression), self.rest_lengths * (1.0 + self.stretch)
        x = positions
        for _ in range(self.iterations):
            along = self.difference @ x
            # |along| as squares times a vector of ones: on the CPU a reduction over a last axis
            # of three costs 2.5x this (18k edges: 97 against 39 us; the sweep: 16.2 -> 13.5 ms).
            squares = along * along
            length = squares.mv(squares.new_ones(3)).sqrt().clamp_min(1e-12)
            excess = length - length.clamp(low, high)  # > 0 too long, < 0 too short, 0 inside the band
            correction = (excess / length)[:, None] * along  # the move that would close the whole excess
            x = x + self.spread @ correction
            if contact is not None:
                x = contact.project(x)
        return x

    def _project_compiled(self, positions: torch.Tensor, contact: ContactPlanes | None) -> torch.Tensor:
        """``project`` by ``physics.strain_sweeps.jacobi_sweeps`` on a copy of (V,3) float32 CPU positions."""
        from hyperbones.physics.strain_sweeps import jacobi_sweeps, rest_length_sweeps

        if self._sweep_arrays is None:  # fixed per garment: made once, not every call
            low, high = self.rest_lengths * (1.0 - self.compression), self.rest_lengths * (1.0 + self.stretch)
            self._sweep_arrays = tuple(item.to("cpu", dtype).contiguous().numpy() for item, dtype in (
                (self.edges[:, 0], torch.int64), (self.edges[:, 1], torch.int64), (low, torch.float32),
                (high, torch.float32), (self.share_first, torch.float32), (self.share_second, torch.float32)))

        if contact is None or not len(contact.vertex):
            plane_vertex, plane_point, plane_normal = _NO_PLANES
        else:
            plane_vertex = contact.vertex.to("cpu", torch.int64).numpy()
            plane_point = contact.point.to("cpu", torch.float32).contiguous().numpy()
            plane_normal = contact.normal.to("cpu", torch.float32).contiguous().numpy()
        x = positions.detach().numpy().copy()  # a C-ordered copy, moved in place
        first, second, low, high, share_first, share_second = self._sweep_arrays
        if self.stretch == 0 and self.compression == 0:  # no band: every edge to its rest length
            rest_length_sweeps(x, first, second, low, share_first, share_second, self.iterations,
                               plane_vertex, plane_point, plane_normal)
        else:
            jacobi_sweeps(x, first, second, low, high, share_first, share_second, self.iterations,
                          plane_vertex, plane_point, plane_normal)
        return torch.from_numpy(x)


_NO_PLANES = (np.zeros(0, np.int64), np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32))


def _compiled_sweeps_apply(positions: torch.Tensor) -> bool:
    """Whether ``StrainLimiter.project`` can run ``physics.strain_sweeps`` on (V,3) ``positions``:
    float32 on the CPU, no gradient asked for, numba installed."""
    if positions.device.type != "cpu" or positions.dtype != torch.float32:
        return False
    if positions.requires_grad and torch.is_grad_enabled():
        return False
    return _HAS_NUMBA


def _numba_installed() -> bool:
    """Whether numba can be imported (a process that blocked it, ``sys.modules["numba"] = None``
    as the torch-only tests do, has none)."""
    try:
        return importlib.util.find_spec("numba") is not None
    except ValueError:  # blocked: sys.modules holds None, whose spec find_spec cannot read
        return False


_HAS_NUMBA = _numba_installed()


__all__ = ["StrainLimiter", "STRETCH_LIMIT", "COMPRESSION_LIMIT", "LIMIT_ITERATIONS"]
