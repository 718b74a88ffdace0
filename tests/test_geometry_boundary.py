"""A garment's borders in order, and the area a hem loop encloses seen from above."""

import math

import pytest
import torch

from hyperbones.geometry.boundary import boundary_loops, lowest_loop
from hyperbones.physics.metrics import enclosed_area


def tube(around: int = 12, rings: int = 3, radius: float = 0.3) -> tuple[torch.Tensor, torch.Tensor]:
    """An open cylinder along Z: (around·rings,3) vertices, (2·around·(rings−1),3) faces."""
    angle = torch.arange(around) * 2 * math.pi / around
    vertices = torch.cat([torch.stack([radius * angle.cos(), radius * angle.sin(), torch.full_like(angle, 0.2 * r)], 1)
                          for r in range(rings)])
    faces = []
    for r in range(rings - 1):
        for i in range(around):
            a, b = r * around + i, r * around + (i + 1) % around
            faces += [[a, b, b + around], [a, b + around, a + around]]
    return vertices, torch.tensor(faces)


def test_a_tube_has_two_ordered_borders_and_its_hem_is_the_lowest():
    vertices, faces = tube()
    loops = boundary_loops(faces)
    assert sorted(len(loop) for loop in loops) == [12, 12]
    for loop in loops:  # each step along a loop is one border edge of the ring
        steps = (vertices[loop] - vertices[loop.roll(-1)]).norm(dim=1)
        assert torch.allclose(steps, torch.full_like(steps, 2 * 0.3 * math.sin(math.pi / 12)), atol=1e-6)
    hem = lowest_loop(faces, vertices)
    assert set(hem.tolist()) == set(range(12))
    assert lowest_loop(torch.tensor([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]), torch.rand(4, 3)) is None  # closed


def test_the_enclosed_area_tells_a_spanning_hem_from_a_wrapped_one():
    vertices, faces = tube(around=64)
    ring = vertices[lowest_loop(faces, vertices)]
    assert float(enclosed_area(ring)) == pytest.approx(math.pi * 0.3**2, rel=0.01)
    # The same loop pinched to a figure eight (one half wrapped the other way round a leg):
    # its two lobes cancel, though its convex hull is the same circle.
    pinched = ring.clone()
    pinched[32:, 1] = -pinched[32:, 1]
    assert float(enclosed_area(pinched)) < 0.05 * math.pi * 0.3**2
    frames = torch.stack([ring, ring * 0.5])  # (T,L,3) -> (T,)
    assert torch.allclose(enclosed_area(frames), torch.tensor([1.0, 0.25]) * enclosed_area(ring), rtol=1e-5)
