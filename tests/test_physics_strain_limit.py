"""Strain limiting: edges end inside their band, pinned vertices stay, contact planes hold."""

import pytest
import torch

from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.material import Material
from hyperbones.physics.strain_limit import StrainLimiter


def _grid(n: int = 8, spacing: float = 0.02) -> tuple[torch.Tensor, torch.Tensor]:
    """A flat n×n vertex grid in the xy-plane: (n²,3) vertices, (2(n−1)²,3) faces."""
    ij = torch.stack(torch.meshgrid(torch.arange(n), torch.arange(n), indexing="ij"), -1).reshape(-1, 2)
    vertices = torch.cat([ij.float() * spacing, torch.zeros(n * n, 1)], dim=1)
    index = torch.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].reshape(-1), index[1:, :-1].reshape(-1), index[:-1, 1:].reshape(-1), index[1:, 1:].reshape(-1)
    faces = torch.cat([torch.stack([a, b, d], 1), torch.stack([a, d, c], 1)])
    return vertices, faces


def _edges(vertices: torch.Tensor, faces: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The cloth's unique edges (E,2) and rest lengths (E,), as the teacher's limiter takes them."""
    cloth = ClothRest.from_mesh(vertices, faces, Material())
    return cloth.edges, cloth.edge_lengths


def _edge_ratios(limiter: StrainLimiter, positions: torch.Tensor) -> torch.Tensor:
    e = limiter.edges
    return (positions[e[:, 1]] - positions[e[:, 0]]).norm(dim=-1) / limiter.rest_lengths


def test_stretched_cloth_is_pulled_back_into_the_band():
    rest, faces = _grid()
    pinned = torch.zeros(len(rest), dtype=torch.bool)
    limiter = StrainLimiter.build(*_edges(rest, faces), torch.full((len(rest),), 1e-4), pinned, stretch=0.01,
                                  compression=0.03, iterations=200)
    torch.manual_seed(0)
    stretched = rest * torch.tensor([1.3, 1.0, 1.0]) + 0.002 * torch.randn_like(rest)
    assert float(_edge_ratios(limiter, stretched).max()) > 1.2
    projected = limiter.project(stretched)
    ratios = _edge_ratios(limiter, projected)
    assert float(ratios.max()) < 1.03 and float(ratios.min()) > 0.96  # from up to 40 % stretch


def test_pinned_vertices_do_not_move_and_in_band_cloth_is_untouched():
    rest, faces = _grid()
    pinned = torch.zeros(len(rest), dtype=torch.bool)
    pinned[:8] = True  # one border row
    limiter = StrainLimiter.build(*_edges(rest, faces), torch.full((len(rest),), 1e-4), pinned)
    pulled = rest.clone()
    pulled[8:, 0] += 0.05  # everything but the pinned row pulled away from it
    projected = limiter.project(pulled)
    torch.testing.assert_close(projected[:8], pulled[:8], atol=0, rtol=0)
    assert float((projected[8:16, 0] - rest[8:16, 0]).abs().max()) < 0.05  # the next row is pulled back
    # A rigid motion keeps every edge length: nothing moves.
    angle = torch.tensor(0.7)
    rotation = torch.tensor([[angle.cos(), -angle.sin(), 0.0], [angle.sin(), angle.cos(), 0.0], [0.0, 0.0, 1.0]])
    moved = rest @ rotation.T + torch.tensor([0.3, -0.1, 1.2])
    torch.testing.assert_close(limiter.project(moved), moved)


def test_bad_band_is_refused():
    rest, faces = _grid(3)
    with pytest.raises(ValueError, match="compression"):
        StrainLimiter.build(*_edges(rest, faces), torch.ones(len(rest)), torch.zeros(len(rest), dtype=torch.bool),
                            compression=1.5)



def test_contact_planes_hold_inside_the_sweeps():
    """Cloth stretched over a plane it must stay on: the planes hold exactly, the band nearly."""
    from hyperbones.physics.contact_planes import ContactPlanes

    rest, faces = _grid()
    limiter = StrainLimiter.build(*_edges(rest, faces), torch.full((len(rest),), 1e-4),
                                  torch.zeros(len(rest), dtype=torch.bool), iterations=200)
    stretched = rest * torch.tensor([1.2, 1.0, 1.0])
    stretched[:, 2] = -0.01  # all 1 cm behind the plane z = 0 that the middle rows are held on
    held = torch.arange(16, 48)
    planes = ContactPlanes(held, torch.zeros(len(held), 3), torch.tensor([0.0, 0.0, 1.0]).expand(len(held), 3))
    projected = limiter.project(stretched, planes)
    assert float(projected[held, 2].min()) >= -1e-6
    ratios = _edge_ratios(limiter, projected)
    assert float(ratios.max()) < 1.05 and float(ratios.min()) > 0.94


def test_compiled_sweeps_match_the_torch_sweeps(monkeypatch):
    """On the CPU without gradients the sweeps run compiled (``physics.strain_sweeps``): the same
    answer as torch's to float32 rounding, with pinned vertices, uneven masses and a vertex held
    by two planes; the input is left as it was, and a gradient still flows through torch's."""
    from hyperbones.physics import strain_limit
    from hyperbones.physics.contact_planes import ContactPlanes

    rest, faces = _grid(12)
    generator = torch.Generator().manual_seed(3)
    masses = 1e-4 * (0.5 + torch.rand(len(rest), generator=generator))
    pinned = torch.zeros(len(rest), dtype=torch.bool)
    pinned[:12] = True
    limiter = StrainLimiter.build(*_edges(rest, faces), masses, pinned, iterations=30)
    moved = rest * torch.tensor([1.15, 0.9, 1.0]) + 0.003 * torch.randn(rest.shape, generator=generator)
    held = torch.tensor([30, 31, 31, 60, 90])  # vertex 31 behind two planes
    normals = torch.nn.functional.normalize(torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.3, 0.0, 1.0],
                                                          [0.0, 0.2, 1.0], [0.0, 0.0, 1.0]]), dim=1)
    planes = ContactPlanes(held, moved[held] + 0.004 * normals, normals)
    before = moved.clone()
    compiled = limiter.project(moved, planes)
    assert strain_limit._compiled_sweeps_apply(moved)
    monkeypatch.setattr(strain_limit, "_HAS_NUMBA", False)
    in_torch = limiter.project(moved, planes)
    torch.testing.assert_close(moved, before, atol=0, rtol=0)
    assert float((in_torch - moved).abs().max()) > 1e-3  # the sweeps did move the cloth
    torch.testing.assert_close(compiled, in_torch, atol=2e-6, rtol=0)
    leaf = moved.clone().requires_grad_(True)
    monkeypatch.setattr(strain_limit, "_HAS_NUMBA", True)
    assert not strain_limit._compiled_sweeps_apply(leaf)
    limiter.project(leaf, planes).sum().backward()
    assert leaf.grad is not None and torch.isfinite(leaf.grad).all()
