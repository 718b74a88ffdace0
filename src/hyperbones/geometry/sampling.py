"""Farthest point sampling: well-spread control points on a surface."""

from __future__ import annotations

import torch

from hyperbones.errors import ParameterError


def farthest_point_sampling(points: torch.Tensor, count: int, first: int | None = None) -> torch.Tensor:
    """Pick ``count`` points, each the farthest (Euclidean) from those picked before it.

    Args:
        points: (N,3) candidate positions.
        count: how many to pick (1 <= count <= N).
        first: index of the first pick; default the point farthest from the centroid,
            so the result depends on the geometry alone (not on vertex order).

    Returns:
        (count,) int64 indices into ``points``, in the order they were picked.

    One pass over the N points per pick: O(count · N), once per garment.
    """
    num_points = points.shape[0]
    if not 1 <= count <= num_points:
        raise ParameterError(f"farthest point sampling: cannot pick {count} of {num_points} points")
    points = points.to(torch.float64)
    if first is None:
        first = int((points - points.mean(0)).norm(dim=1).argmax())
    picked = torch.empty(count, dtype=torch.int64)
    picked[0] = first
    nearest = (points - points[first]).norm(dim=1)
    for i in range(1, count):
        picked[i] = int(nearest.argmax())
        nearest = torch.minimum(nearest, (points - points[picked[i]]).norm(dim=1))
    return picked
