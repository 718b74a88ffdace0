"""The teacher's integrator."""

import torch

from hyperbones.models.teacher import integrate


def test_integrate_is_symplectic_euler_with_pinned_vertices_following():
    positions = torch.zeros(3, 3)
    velocities = torch.tensor([[0.01, 0.0, 0.0]] * 3)
    acceleration = torch.tensor([[0.0, 0.0, -0.002]] * 3)
    pinned = torch.tensor([False, False, True])
    pinned_next = torch.full((3, 3), 0.5)
    x, v = integrate(positions, velocities, acceleration, pinned, pinned_next)
    assert torch.allclose(v[:2], torch.tensor([0.01, 0.0, -0.002]).expand(2, 3))
    assert torch.allclose(x[:2], v[:2])  # x(t+1) = x(t) + v(t+1)
    assert torch.equal(x[2], pinned_next[2]) and torch.equal(v[2], pinned_next[2])
