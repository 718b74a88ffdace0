"""The teacher's integrator and its hard contact, on the real body."""

import torch

from hyperbones.geometry.proximity import BodyProximity
from hyperbones.models.teacher import integrate, resolve_contact


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


def test_resolve_contact_moves_only_cloth_inside_the_body(body):
    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    v = body.rest_vertices
    torso = torch.nonzero((v[:, 2] > 1.0) & (v[:, 2] < 1.3) & (v[:, 0].abs() < 0.08)).squeeze(1)
    skin = v[torso[torch.linspace(0, len(torso) - 1, 4).long()]]  # front and back of the chest and belly
    normals = proximity.query(skin, max_distance=0.1).normal
    positions = torch.cat([skin - 0.01 * normals, skin + 0.05 * normals])  # 1 cm inside, 5 cm outside
    velocities = torch.full_like(positions, 0.001)
    movable = torch.ones(len(positions), dtype=torch.bool)
    movable[0] = False  # a pinned vertex stays where it is
    nearest = proximity.query(positions, max_distance=0.1)
    assert (nearest.signed_distance[:4] < 0).all()
    moved, moved_velocities = resolve_contact(positions, velocities, nearest, movable, margin=2e-3)
    after = proximity.query(moved, max_distance=0.1).signed_distance
    assert torch.allclose(after[1:4], torch.full((3,), 2e-3), atol=2e-4)
    assert torch.equal(moved[0], positions[0]) and torch.equal(moved[4:], positions[4:])
    # The push becomes velocity (position-based dynamics): v + (x_new − x_old).
    assert torch.allclose(moved_velocities, velocities + (moved - positions))
    assert float((moved_velocities[1:4] - velocities[1:4]).norm(dim=-1).min()) > 0.01
