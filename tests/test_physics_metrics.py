import math

import pytest
import torch

from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.energies import stretching_energy
from hyperbones.physics.material import Material
from hyperbones.physics.metrics import (
    HOOD_COLLISION_THRESHOLD,
    area_error_pct,
    collision_pct,
    edge_error_pct,
    mean_energies,
    per_frame_energies,
)

F64 = torch.float64


def fan_mesh() -> tuple[torch.Tensor, torch.Tensor]:
    """A hexagonal fan of six triangles around a centre vertex, slightly domed, 10 cm across."""
    angles = torch.arange(6, dtype=F64) * (math.pi / 3)
    rim = torch.stack([0.1 * angles.cos(), 0.1 * angles.sin(), torch.zeros(6, dtype=F64)], -1)
    vertices = torch.cat([torch.tensor([[0.0, 0.0, 0.02]], dtype=F64), rim])
    faces = torch.stack([torch.zeros(6, dtype=torch.int64), torch.arange(1, 7), torch.arange(1, 7) % 6 + 1], -1)
    return vertices, faces


@pytest.fixture()
def rest():
    return ClothRest.from_mesh(*fan_mesh())


def test_uniform_scaling_gives_ten_percent_edge_and_21_percent_area_error(rest):
    frames = torch.stack([rest.rest_vertices, rest.rest_vertices * 1.1 + 0.3])  # frame 0 exact, frame 1 scaled
    assert torch.allclose(edge_error_pct(frames[1:], rest), torch.tensor(10.0, dtype=F64))
    assert torch.allclose(area_error_pct(frames[1:], rest), torch.tensor(21.0, dtype=F64))
    assert torch.allclose(edge_error_pct(frames, rest), torch.tensor(5.0, dtype=F64))  # mean over frames
    assert torch.allclose(edge_error_pct(rest.rest_vertices * 0.9, rest), torch.tensor(10.0, dtype=F64))


def test_metrics_use_the_3d_template_not_uvs():
    vertices, faces = fan_mesh()
    stretched_uv = ClothRest.from_mesh(vertices, faces, uv_rest=vertices[:, :2] * 2.0)
    assert edge_error_pct(vertices, stretched_uv) < 1e-12 and area_error_pct(vertices, stretched_uv) < 1e-12


def test_collision_pct_on_hand_made_distances():
    distances = torch.tensor([[-0.01, -1e-4, 5e-4, 2e-3], [0.0, 0.05, float("inf"), -2.0]])
    assert collision_pct(distances) == pytest.approx(100 * 3 / 8)
    assert collision_pct(distances, threshold=HOOD_COLLISION_THRESHOLD) == pytest.approx(100 * 5 / 8)


def test_per_frame_energies_shapes_and_zero_inertia_when_static(rest):
    static = rest.rest_vertices.expand(5, -1, -1)
    energies = per_frame_energies(static, rest)
    assert set(energies) == {"stretching", "bending", "inertia", "gravity"}
    assert all(value.shape == (3,) for value in energies.values())
    assert torch.all(energies["inertia"] == 0)
    assert torch.allclose(energies["stretching"], torch.zeros(3, dtype=F64), atol=1e-15)
    # The domed fan at rest is bent: HOOD's θ⁰ = 0 charges it.
    assert torch.all(energies["bending"] > 0)
    # Uniform motion is inertia-free too; gravity is absolute height energy.
    velocity = torch.tensor([0.01, 0.0, 0.02], dtype=F64)
    moving = rest.rest_vertices + torch.arange(5, dtype=F64)[:, None, None] * velocity
    energies = per_frame_energies(moving, rest)
    assert energies["inertia"].abs().max() < 1e-20
    mass = rest.vertex_masses.sum()
    expected_gravity = (rest.vertex_masses * 9.81 * rest.rest_vertices[:, 2]).sum() + mass * 9.81 * 0.02 * torch.arange(2, 5)
    assert torch.allclose(energies["gravity"], expected_gravity)


def test_per_frame_energies_inertia_uses_the_previous_two_frames(rest):
    frames = rest.rest_vertices.repeat(3, 1, 1)
    frames[2, :, 2] += 0.001  # a 1 mm jump on the last frame only
    inertia = per_frame_energies(frames, rest, dt=0.1)["inertia"]
    assert torch.allclose(inertia, (rest.vertex_masses.sum() * 1e-6 / (2 * 0.01)).reshape(1))


def test_per_frame_energies_use_hood_defaults_unless_told(rest):
    stiff = rest.with_material(Material(lame_mu=50000.0, density=0.4))
    frames = (rest.rest_vertices * 1.05).expand(3, -1, -1)
    default = per_frame_energies(frames, stiff)
    assert torch.allclose(default["stretching"], stretching_energy(frames[2:], rest))
    custom = per_frame_energies(frames, rest, material=stiff.material)
    assert torch.allclose(custom["stretching"], stretching_energy(frames[2:], stiff))
    assert torch.allclose(custom["gravity"], default["gravity"] * 0.4 / Material().density)  # masses follow density
    means = mean_energies(frames, rest)
    assert means["stretching"] == pytest.approx(float(default["stretching"].mean()))
    with pytest.raises(ValueError):
        per_frame_energies(frames[:2], rest)
