"""Farthest point sampling."""

import pytest
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.sampling import farthest_point_sampling


def test_picks_are_distinct_and_spread():
    grid = torch.stack(torch.meshgrid(torch.linspace(0, 1, 21), torch.linspace(0, 1, 21), indexing="ij"), -1)
    points = torch.cat([grid.reshape(-1, 2), torch.zeros(441, 1)], 1)
    picked = farthest_point_sampling(points, 4)
    assert len(set(picked.tolist())) == 4
    # On a square the first four picks are its corners.
    corners = {(0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1.0, 1.0)}
    assert {tuple(round(float(c), 3) for c in points[i, :2]) for i in picked} == corners


def test_covering_radius_shrinks_like_uniform_spacing():
    torch.manual_seed(0)
    points = torch.rand(4000, 3)
    for count in (16, 64):
        picked = farthest_point_sampling(points, count)
        radius = torch.cdist(points, points[picked]).min(1).values.max()
        # A cube of side 1 split into `count` cells of side count^(-1/3): the farthest point
        # of a good sample is within about one cell diagonal.
        assert radius < 3 ** 0.5 * count ** (-1 / 3)


def test_independent_of_vertex_order():
    torch.manual_seed(1)
    points = torch.rand(500, 3)
    order = torch.randperm(500)
    a = points[farthest_point_sampling(points, 10)]
    b = points[order][farthest_point_sampling(points[order], 10)]
    assert torch.equal(a, b)


def test_bad_count():
    with pytest.raises(ParameterError, match="cannot pick 5 of 3"):
        farthest_point_sampling(torch.rand(3, 3), 5)
