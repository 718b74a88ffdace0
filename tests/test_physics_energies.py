import math

import pytest
import torch

from hyperbones.physics.cloth import ClothRest, dihedral_angles
from hyperbones.physics.energies import (
    bending_energy,
    collision_energy,
    friction_energy,
    gravity_energy,
    inertia_energy,
    inertia_energy_velocity,
    stretching_energy,
)
from hyperbones.physics.material import Material

F64 = torch.float64
MATERIAL = Material()


def grid_mesh(n: int = 4, size: float = 0.3) -> tuple[torch.Tensor, torch.Tensor]:
    """(n*n,3) flat square grid in the XY plane and its 2(n−1)² triangles."""
    coords = torch.linspace(0, size, n, dtype=F64)
    yy, xx = torch.meshgrid(coords, coords, indexing="ij")
    vertices = torch.stack([xx, yy, torch.zeros_like(xx)], -1).reshape(-1, 3)
    corner = (torch.arange(n - 1)[:, None] * n + torch.arange(n - 1)[None, :]).reshape(-1)
    faces = torch.cat([torch.stack([corner, corner + 1, corner + n + 1], -1),
                       torch.stack([corner, corner + n + 1, corner + n], -1)])
    return vertices, faces


def hinge(theta: float, scale: float = 0.1) -> tuple[torch.Tensor, torch.Tensor]:
    """Two triangles sharing the edge (0,0,0)-(s,0,0), the second folded by theta about it."""
    vertices = scale * torch.tensor([[0, 0, 0], [1, 0, 0], [0.5, 1, 0],
                                     [0.5, -math.cos(theta), math.sin(theta)]], dtype=F64)
    return vertices, torch.tensor([[0, 1, 2], [1, 0, 3]])


def random_rotation(seed: int) -> torch.Tensor:
    q, _ = torch.linalg.qr(torch.randn(3, 3, dtype=F64, generator=torch.Generator().manual_seed(seed)))
    return q * torch.sign(torch.det(q))


@pytest.mark.parametrize("stretch", [1.0, 1.1, 0.8])
def test_uniaxially_stretched_triangle_matches_hand_stvk(stretch):
    rest_2d = 0.2 * torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.2, 0.0], [0.3, 0.9, 0.0]], dtype=F64)
    rotation = random_rotation(0)
    rest = ClothRest.from_mesh(rest_2d @ rotation.T, torch.tensor([[0, 1, 2]]))  # rest off the XY plane
    deformed = rest_2d * torch.tensor([stretch, 1.0, 1.0], dtype=F64)
    # G = diag((s²−1)/2, 0): tr(SᵀG) = μ g² + ½λ g² with g = (s²−1)/2.
    g = (stretch**2 - 1) / 2
    area = 0.5 * 0.04 * (1.0 * 0.9 - 0.2 * 0.3)
    expected = area * MATERIAL.thickness * (MATERIAL.lame_mu + 0.5 * MATERIAL.lame_lambda) * g**2
    assert torch.allclose(stretching_energy(deformed, rest), torch.tensor(expected, dtype=F64), rtol=1e-10, atol=1e-15)
    # Rigid motions cost nothing.
    assert stretching_energy(rest_2d @ random_rotation(1).T + 0.5, rest).abs() < 1e-15


def test_uv_rest_gives_the_same_membrane_energy():
    vertices, faces = grid_mesh(3)
    rest = ClothRest.from_mesh(vertices, faces)
    uv_rest = ClothRest.from_mesh(vertices, faces, uv_rest=vertices[:, :2])
    per_corner = ClothRest.from_mesh(vertices, faces, uv_rest=vertices[faces][..., :2])
    x = vertices + 0.01 * torch.randn(vertices.shape, dtype=F64, generator=torch.Generator().manual_seed(2))
    for other in (uv_rest, per_corner):
        assert torch.allclose(stretching_energy(x, rest), stretching_energy(x, other), rtol=1e-10)
        assert torch.allclose(rest.vertex_masses, other.vertex_masses)


@pytest.mark.parametrize("theta", [0.0, 1e-4, 0.3, 1.0, 2.5])
def test_folded_hinge_matches_closed_form_bending(theta):
    flat, faces = hinge(0.0)
    rest = ClothRest.from_mesh(flat, faces)
    assert rest.hinges.shape == (1, 4) and rest.num_nonmanifold_edges == 0
    assert rest.hinge_rest_angles.abs().max() < 1e-12
    folded, _ = hinge(theta)
    assert torch.allclose(dihedral_angles(folded, rest.hinges).abs(), torch.tensor([theta], dtype=F64), atol=1e-12)
    length, area = 0.1, 0.5 * 0.1 * 0.1  # rest edge length and each rest face's area
    expected = MATERIAL.bending * length**2 / (4 * 2 * area) * theta**2 / 2
    assert torch.allclose(bending_energy(folded, rest), torch.tensor(expected, dtype=F64), rtol=1e-9, atol=1e-30)


def test_bending_ignores_face_winding_and_rigid_motion():
    flat, faces = hinge(0.0)
    inconsistent = ClothRest.from_mesh(flat, torch.tensor([[0, 1, 2], [0, 1, 3]]))  # both faces wind i -> j
    folded, _ = hinge(0.7)
    expected = bending_energy(folded, ClothRest.from_mesh(flat, faces))
    assert torch.allclose(bending_energy(folded, inconsistent), expected)
    assert torch.allclose(bending_energy(folded @ random_rotation(3).T - 2.0, inconsistent), expected)


def test_non_manifold_edge_is_skipped_and_counted():
    vertices = torch.tensor([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1]], dtype=F64)
    faces = torch.tensor([[0, 1, 2], [1, 0, 3], [0, 1, 4]])  # three faces on edge 0-1
    rest = ClothRest.from_mesh(vertices, faces)
    assert rest.num_nonmanifold_edges == 1 and rest.hinges.shape == (0, 4)
    assert bending_energy(vertices, rest) == 0
    assert rest.edges.shape == (7, 2)


def test_grid_tables_masses_and_degenerate_faces():
    vertices, faces = grid_mesh(4, size=0.3)
    rest = ClothRest.from_mesh(vertices, faces)
    assert rest.hinges.shape[0] == 9 + 2 * 2 * 3  # cell diagonals + interior grid lines
    assert rest.edges.shape[0] == rest.hinges.shape[0] + rest.num_boundary_edges == 33
    assert torch.allclose(rest.vertex_masses.sum(), torch.tensor(MATERIAL.density * 0.09, dtype=F64))
    degenerate = ClothRest.from_mesh(vertices, torch.cat([faces, torch.tensor([[0, 1, 2]])]))  # collinear
    assert degenerate.num_degenerate_faces == 1 and torch.isfinite(degenerate.dm_inv).all()
    assert torch.allclose(stretching_energy(vertices * 1.1, degenerate), stretching_energy(vertices * 1.1, rest))


def test_gravity_of_a_single_vertex_mass():
    vertices = torch.tensor([[0, 0, 0], [0.2, 0, 0], [0, 0.1, 0]], dtype=F64)
    rest = ClothRest.from_mesh(vertices, torch.tensor([[0, 1, 2]]))
    mass = MATERIAL.density * 0.5 * 0.2 * 0.1 / 3
    assert torch.allclose(rest.vertex_masses, torch.full((3,), mass, dtype=F64))
    lifted = vertices.clone()
    lifted[2, 2] = 1.5
    assert torch.allclose(gravity_energy(lifted, rest), torch.tensor(mass * 9.81 * 1.5, dtype=F64))
    assert torch.allclose(gravity_energy(lifted, rest, g=1.0), torch.tensor(mass * 1.5, dtype=F64))


def test_collision_penalty_of_a_vertex_one_millimetre_inside():
    x = torch.tensor([[0.3, -0.2, -1e-3], [0.0, 0.0, 5e-3], [0.0, 0.0, -0.5]], dtype=F64)
    points = torch.zeros(3, 3, dtype=F64)
    normals = torch.tensor([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 0]], dtype=F64)  # third: no face found
    weight = 5e5
    expected = weight * (2e-3 + 1e-3) ** 3
    assert torch.allclose(collision_energy(x, points, normals, eps=2e-3, weight=weight), torch.tensor(expected, dtype=F64))
    masked = collision_energy(x, points, normals, mask=torch.tensor([False, True, True]))
    assert masked == 0


def test_inertia_zero_for_uniform_motion_and_hand_value_when_accelerated():
    vertices, faces = grid_mesh(3)
    rest = ClothRest.from_mesh(vertices, faces)
    step = torch.tensor([0.01, -0.02, 0.005], dtype=F64)
    dt = 1.0 / 30.0
    assert inertia_energy(vertices + 2 * step, vertices + step, vertices, rest, dt).abs() < 1e-20
    kick = torch.tensor([0.0, 0.0, 0.003], dtype=F64)
    accelerated = inertia_energy(vertices + 2 * step + kick, vertices + step, vertices, rest, dt)
    expected = rest.vertex_masses.sum() * kick.square().sum() / (2 * dt * dt)
    assert torch.allclose(accelerated, expected)
    velocity = inertia_energy_velocity(vertices + 2 * step + kick, vertices + step, (step / dt).expand(9, 3), rest, dt)
    assert torch.allclose(velocity, expected)


def test_friction_zero_when_moving_with_the_body_and_mu_m_g_slip_otherwise():
    vertices, faces = grid_mesh(3)
    rest = ClothRest.from_mesh(vertices, faces)
    normals = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand(9, 3)
    body_curr = vertices - torch.tensor([0, 0, 1e-3], dtype=F64)  # garment 1 mm above the skin
    body_motion = torch.tensor([0.02, 0.01, 0.03], dtype=F64)
    args = dict(body_next_points=body_curr + body_motion, body_curr_points=body_curr, normals=normals, rest=rest)
    assert friction_energy(vertices + body_motion, vertices, **args) == 0
    slip = torch.tensor([0.004, -0.003, 0.0007], dtype=F64)  # 5 mm tangential, plus a normal part
    energy = friction_energy(vertices + body_motion + slip, vertices, **args)
    expected = 0.5 * rest.vertex_masses.sum() * 9.81 * 5e-3
    assert torch.allclose(energy, expected, rtol=1e-3)
    far = friction_energy(vertices + 0.05 + slip, vertices + 0.05, **args)  # 5 cm off the body: no contact
    assert far == 0


def _noisy(vertices: torch.Tensor, amplitude: float, seed: int) -> torch.Tensor:
    noise = torch.randn(vertices.shape, dtype=F64, generator=torch.Generator().manual_seed(seed))
    return (vertices + amplitude * noise).requires_grad_(True)


@pytest.mark.parametrize("amplitude", [0.0, 1e-7, 1e-2])
def test_membrane_and_bending_gradients_match_finite_differences(amplitude):
    vertices, faces = grid_mesh(3, size=0.1)
    rest = ClothRest.from_mesh(_noisy(vertices, 5e-3, 0).detach(), faces)
    x = _noisy(vertices, amplitude, 1)  # amplitude 0 and 1e-7: exactly and nearly flat hinges
    assert torch.autograd.gradcheck(lambda v: bending_energy(v, rest), (x,))
    assert torch.autograd.gradcheck(lambda v: stretching_energy(v, rest), (x,))
    assert torch.isfinite(torch.autograd.grad(bending_energy(x, rest), x)[0]).all()


def test_other_energy_gradients_match_finite_differences():
    vertices, faces = grid_mesh(3, size=0.1)
    rest = ClothRest.from_mesh(vertices, faces)
    x_prev, x_curr = _noisy(vertices, 1e-2, 2).detach(), _noisy(vertices, 1e-2, 3).detach()
    x = _noisy(vertices, 1e-2, 4)
    assert torch.autograd.gradcheck(lambda v: gravity_energy(v, rest), (x,))
    assert torch.autograd.gradcheck(lambda v: inertia_energy(v, x_curr, x_prev, rest), (x,))
    assert torch.autograd.gradcheck(lambda v: inertia_energy_velocity(v, x_curr, x_prev, rest), (x,))
    normals = torch.nn.functional.normalize(torch.randn(9, 3, dtype=F64, generator=torch.Generator().manual_seed(5)), dim=-1)
    body = vertices - 1e-3 * normals  # every vertex about 1 mm off its plane, some pushed inside by x's noise
    assert collision_energy(x, body, normals) > 0
    assert torch.autograd.gradcheck(lambda v: collision_energy(v, body, normals), (x,))
    args = dict(body_next_points=body + 0.01, body_curr_points=body, normals=normals, rest=rest, contact_radius=0.1)
    assert friction_energy(x, vertices, **args) > 0
    assert torch.autograd.gradcheck(lambda v: friction_energy(v, vertices, **args), (x,))
    # Zero slip: the smooth norm still has a (zero) gradient instead of NaN.
    at_rest = (vertices + 0.01).requires_grad_(True)
    grad = torch.autograd.grad(friction_energy(at_rest, vertices, **args), at_rest)[0]
    assert torch.isfinite(grad).all() and grad.abs().max() == 0


def test_batched_calls_equal_per_sample_calls():
    vertices, faces = grid_mesh(4, size=0.2)
    rest = ClothRest.from_mesh(vertices, faces)
    batch = torch.stack([_noisy(vertices, 1e-2, seed).detach() for seed in range(6)]).reshape(2, 3, 16, 3)
    prev, curr = batch.roll(1, dims=1), batch.roll(2, dims=1)
    normals = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand_as(batch)
    energies = {
        "stretch": lambda s: stretching_energy(batch[s], rest),
        "bend": lambda s: bending_energy(batch[s], rest),
        "gravity": lambda s: gravity_energy(batch[s], rest),
        "inertia": lambda s: inertia_energy(batch[s], curr[s], prev[s], rest),
        "collision": lambda s: collision_energy(batch[s], curr[s], normals[s]),
        "friction": lambda s: friction_energy(batch[s], curr[s], prev[s], curr[s], normals[s], rest, contact_radius=1.0),
    }
    for name, energy in energies.items():
        whole = energy((slice(None), slice(None)))
        assert whole.shape == (2, 3), name
        each = torch.stack([torch.stack([energy((b, t)) for t in range(3)]) for b in range(2)])
        assert torch.allclose(whole, each, rtol=1e-12, atol=1e-18), name


@pytest.mark.parametrize("height", [1e-9, 1e-12, 0.0])
def test_a_face_flattened_to_a_sliver_exerts_no_bending_force(height):
    """Contact can flatten a triangle onto a line; its dihedral angle is then undefined and the
    discrete-shell gradient grows as 1/height (9e6 N at 1e-12 m in float32, NaN forces in a
    rollout). Below the near-degenerate bound the hinge is treated as flat."""
    rest_vertices = torch.tensor([[0, 0, 0], [0.02, 0, 0], [0.01, 0.01, 0], [0.01, -0.01, 0.0]])
    rest = ClothRest.from_mesh(rest_vertices, torch.tensor([[0, 1, 2], [1, 0, 3]]))
    sliver = torch.tensor([[0, 0, 0], [0.02, 0, 0], [0.01, height, 0.0], [0.01, -0.01, 0.005]], requires_grad=True)
    (gradient,) = torch.autograd.grad(bending_energy(sliver, rest), sliver)
    assert torch.equal(gradient, torch.zeros_like(gradient))
    healthy = torch.tensor([[0, 0, 0], [0.02, 0, 0], [0.01, 1e-3, 0.0], [0.01, -0.01, 0.005]], requires_grad=True)
    (gradient,) = torch.autograd.grad(bending_energy(healthy, rest), healthy)
    assert gradient.abs().max() > 1e-3  # a thin but real face (height/edge 0.05) still bends
