import roma
import torch

from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.geometry.rotations import minimal_rotation, rotation_angle_deg, rot_z, slerp_rotmat


def test_minimal_rotation_maps_direction_including_antiparallel():
    torch.manual_seed(0)
    src, dst = torch.randn(100, 3, dtype=torch.float64), torch.randn(100, 3, dtype=torch.float64)
    dst[0] = -src[0]
    rot = minimal_rotation(src, dst)
    mapped = (rot @ (src / src.norm(dim=-1, keepdim=True)).unsqueeze(-1)).squeeze(-1)
    assert torch.allclose(mapped, dst / dst.norm(dim=-1, keepdim=True), atol=1e-9)
    assert torch.allclose(torch.det(rot), torch.ones(100, dtype=torch.float64))


def test_slerp_endpoints_midpoint_and_shortest_arc():
    r0 = rot_z(torch.tensor([0.0]))
    r1 = rot_z(torch.tensor([1.2]))
    assert torch.allclose(slerp_rotmat(r0, r1, torch.tensor([0.0])), r0, atol=1e-6)
    assert torch.allclose(slerp_rotmat(r0, r1, torch.tensor([1.0])), r1, atol=1e-6)
    assert torch.allclose(slerp_rotmat(r0, r1, torch.tensor([0.5])), rot_z(torch.tensor([0.6])), atol=1e-6)
    far = rot_z(torch.tensor([3.0]))
    assert rotation_angle_deg(r0, slerp_rotmat(r0, far, torch.tensor([0.5]))).item() < 90


def test_lbs_rigid_single_joint_and_blend():
    torch.manual_seed(1)
    rest = torch.randn(50, 3)
    rot = roma.random_rotmat(2)
    transforms = torch.eye(4).repeat(1, 2, 1, 1)
    transforms[0, :, :3, :3] = rot
    transforms[0, 1, :3, 3] = torch.tensor([1.0, 2.0, 3.0])
    only_first = torch.zeros(50, 2)
    only_first[:, 0] = 1
    posed = linear_blend_skinning(rest, only_first, transforms)
    assert torch.allclose(posed[0], rest @ rot[0].T, atol=1e-5)
    half = torch.full((50, 2), 0.5)
    expected = 0.5 * (rest @ rot[0].T) + 0.5 * (rest @ rot[1].T + torch.tensor([1.0, 2.0, 3.0]))
    assert torch.allclose(linear_blend_skinning(rest, half, transforms, frames_per_chunk=1)[0], expected, atol=1e-5)
