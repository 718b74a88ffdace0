"""Virtual bones: placement, weights, and posing on a real template and the Anny body."""

import math

import pytest
import torch

from hyperbones.body.skeleton import skinning_transforms
from hyperbones.errors import ParameterError
from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.geometry.rotations import rot_z
from hyperbones.rig.virtual_bones import NUM_BONES, VirtualBones


@pytest.fixture(scope="module")
def pants(body):
    from hyperbones.garment.templates import make_template

    return make_template("pants", body, vertices=1500)


@pytest.fixture(scope="module")
def rig(pants, body):
    return VirtualBones.bind(pants, body)


def test_bones_and_weights(rig, pants):
    assert rig.rest_positions.shape == (NUM_BONES, 3)
    assert len(set(rig.garment_vertex.tolist())) == NUM_BONES
    assert torch.allclose(rig.rest_positions, pants.vertices[rig.garment_vertex])
    assert torch.allclose(rig.joint_weights.sum(1), torch.ones(NUM_BONES), atol=1e-5)
    weights = rig.log_weights.exp()
    assert weights.shape == (pants.num_vertices, NUM_BONES)
    assert torch.allclose(weights.sum(1), torch.ones(pants.num_vertices), atol=1e-5)
    # Each bone's own vertex follows that bone most.
    assert torch.equal(weights[rig.garment_vertex].argmax(1), torch.arange(NUM_BONES))


def test_geodesic_weights_do_not_couple_the_legs(rig, pants):
    """Below the knee, a pants vertex takes almost nothing from the other leg's bones, which
    straight-line distances would give it (18 % on this garment)."""
    vertices, bones = pants.vertices, rig.rest_positions
    shin = (vertices[:, 2] < 0.6) & (vertices[:, 0].abs() > 0.03)
    other_leg = (torch.sign(vertices[:, 0])[:, None] != torch.sign(bones[:, 0])[None]) & (bones[:, 2] < 0.6)[None]
    crossing = (rig.log_weights.exp() * other_leg).sum(1)[shin]
    assert shin.sum() > 100 and float(crossing.max()) < 0.01


def test_rest_pose_and_rigid_motion(rig, pants):
    rotation = rot_z(torch.tensor(0.7))
    transform = torch.eye(4)
    transform[:3, :3], transform[:3, 3] = rotation, torch.tensor([0.3, -1.0, 0.2])
    skinning = torch.stack([torch.eye(4), transform])[:, None].expand(2, 31, 4, 4)
    rotations, positions = rig.pose(skinning)
    assert rotations.shape == (2, NUM_BONES, 3, 3) and positions.shape == (2, NUM_BONES, 3)
    assert torch.allclose(rotations[0], torch.eye(3).expand(NUM_BONES, 3, 3), atol=1e-6)
    assert torch.allclose(positions[0], rig.rest_positions, atol=1e-6)
    assert torch.allclose(rotations[1], rotation.expand(NUM_BONES, 3, 3), atol=1e-6)
    garment = linear_blend_skinning(pants.vertices, rig.log_weights.exp(),
                                    skinning_transforms(rig.rest_positions, rotations, positions))
    assert torch.allclose(garment[0], pants.vertices, atol=1e-5)
    assert torch.allclose(garment[1], pants.vertices @ rotation.T + transform[:3, 3], atol=1e-5)


def test_bones_follow_the_skeleton(rig, body):
    """A bent knee moves the bones on the shin and leaves those on the hips alone."""
    from hyperbones.body.skeleton import joint_index

    rotations = torch.eye(3).repeat(1, 31, 1, 1)
    knee = joint_index("LeftLeg")
    bend = torch.tensor([[1.0, 0, 0], [0, math.cos(1.0), -math.sin(1.0)], [0, math.sin(1.0), math.cos(1.0)]])
    rotations[0, knee] = bend
    rotations[0, joint_index("LeftFoot")] = bend
    rotations[0, joint_index("LeftToeBase")] = bend
    posed = body.pose(rotations, body.rest_root[None], with_vertices=False)
    _, positions = rig.pose(posed.skinning_transforms)
    moved = (positions[0] - rig.rest_positions).norm(dim=1)
    shin = rig.joint_weights[:, knee] > 0.9
    hips = rig.rest_positions[:, 2] > 0.9
    assert shin.any() and hips.any()
    assert float(moved[shin].min()) > 0.02 and float(moved[hips].max()) < 1e-4


def test_too_many_bones(body):
    from hyperbones.garment.templates import make_template

    garment = make_template("tshirt", body, vertices=1500)
    with pytest.raises(ParameterError, match="virtual bones asked for"):
        VirtualBones.bind(garment, body, num_bones=garment.num_vertices + 1)


def test_bones_bind_at_the_rest_shape_when_given(rig, pants, body):
    """A garment moved off its rest shape (as a drape moves it) keeps the bones' skinning
    weights of the rest shape when that is given; bound where it is, they change."""
    moved = pants.with_vertices(pants.vertices + torch.tensor([0.04, 0.0, -0.03]))
    at_rest = VirtualBones.bind(moved, body, rest_vertices=pants.vertices)
    assert torch.equal(at_rest.garment_vertex, rig.garment_vertex)  # same places on the cloth
    assert torch.allclose(at_rest.rest_positions, moved.vertices[rig.garment_vertex])
    assert torch.allclose(at_rest.joint_weights, rig.joint_weights)
    where_it_is = VirtualBones.bind(moved, body)
    assert (where_it_is.joint_weights - rig.joint_weights).abs().sum(1).max() > 0.05
    with pytest.raises(ParameterError, match="rest shape .* does not match"):
        VirtualBones.bind(moved, body, rest_vertices=pants.vertices[:-1])
