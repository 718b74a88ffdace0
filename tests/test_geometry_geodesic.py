"""Geodesic distances (heat method through potpourri3d)."""

import math

import pytest
import torch
import trimesh

from hyperbones.errors import ParameterError
from hyperbones.geometry.geodesic import geodesic_distances, mesh_components


def _sphere():
    mesh = trimesh.creation.icosphere(subdivisions=4)
    return torch.tensor(mesh.vertices, dtype=torch.float32), torch.tensor(mesh.faces, dtype=torch.int64)


def test_great_circle_distance_on_a_sphere():
    vertices, faces = _sphere()
    pole = int(vertices[:, 2].argmax())
    distance = geodesic_distances(vertices, faces, torch.tensor([pole]))[0]
    exact = torch.arccos((vertices[:, 2] / vertices.norm(dim=1)).clamp(-1, 1))
    assert float((distance - exact).abs().max()) < 0.05 * math.pi  # the heat method's smoothing
    # Along the surface, not through it: the far pole is π away, not 2.
    assert float(distance[int(vertices[:, 2].argmin())]) == pytest.approx(math.pi, abs=0.05)


def test_other_pieces_are_unreachable():
    vertices, faces = _sphere()
    two = torch.cat([vertices, vertices + torch.tensor([3.0, 0, 0])])
    both = torch.cat([faces, faces + len(vertices)])
    assert len(set(mesh_components(len(two), both).tolist())) == 2
    distance = geodesic_distances(two, both, torch.tensor([0, len(vertices)]))
    assert torch.isinf(distance[0, len(vertices):]).all() and torch.isfinite(distance[0, :len(vertices)]).all()
    assert torch.isinf(distance[1, :len(vertices)]).all()
    assert torch.allclose(distance[0, :len(vertices)], distance[1, len(vertices):], atol=1e-5)


def test_bad_source():
    vertices, faces = _sphere()
    with pytest.raises(ParameterError, match="out of range"):
        geodesic_distances(vertices, faces, torch.tensor([len(vertices)]))
