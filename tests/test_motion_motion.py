import pytest
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.rotations import rot_z, rotation_angle_deg
from hyperbones.motion.motion import Motion, heading_angle, resample_poses


def _spin(frames=5, fps=120.0):
    angles = torch.linspace(0, 1.0, frames)
    rot = rot_z(angles)[:, None].expand(-1, 31, -1, -1).contiguous()
    root = torch.stack([angles, torch.zeros(frames), torch.ones(frames)], -1)
    return Motion(rot, root, fps, "spin")


def test_resample_hits_source_times():
    motion = _spin(frames=9, fps=120.0)
    out = motion.resample(30.0)
    assert out.num_frames == 3 and out.fps == 30.0
    assert torch.allclose(out.joint_rotations[1], motion.joint_rotations[4], atol=1e-6)
    half = resample_poses(motion.joint_rotations, motion.root_translation, 120.0, 240.0, "x")
    assert torch.allclose(half.root_translation[1], (motion.root_translation[0] + motion.root_translation[1]) / 2)


def test_blend_in_starts_in_apose_with_heading_and_is_smooth():
    motion = _spin()
    rest_root = torch.tensor([0.0, 0.0, 0.9])
    out = motion.blend_in(10, rest_root)
    assert out.num_frames == motion.num_frames + 10
    assert rotation_angle_deg(out.joint_rotations[0, 5], torch.eye(3)).item() < 1e-3  # yaw 0 at frame 0
    assert float(out.root_translation[0, 2]) == pytest.approx(0.9)
    assert torch.equal(out.joint_rotations[10:], motion.joint_rotations)
    steps = rotation_angle_deg(out.joint_rotations[1:], out.joint_rotations[:-1])
    assert steps.max() < 30
    assert motion.blend_in(0, rest_root) is motion


def test_blend_in_arrives_with_the_motions_velocity():
    """A clip that starts mid-run: the root speeds up from rest to the clip's 3 m/s and a
    slowly turning joint keeps its 1 rad/s, so the join has no velocity jump."""
    fps, frames, n = 30.0, 20, 15
    t = torch.arange(frames) / fps
    rot = torch.eye(3).repeat(frames, 31, 1, 1)
    rot[:, 7] = rot_z(1.0 * t)  # joint 7 turns at 1 rad/s about z
    root = torch.stack([3.0 * t, torch.zeros(frames), torch.full((frames,), 0.95)], -1)
    out = Motion(rot, root, fps, "run").blend_in(n, torch.tensor([0.0, 0.0, 0.9]))
    velocity = (out.root_translation[1:] - out.root_translation[:-1]) * fps  # (T-1,3)
    assert float(velocity[0].norm()) < 0.05  # the A-pose starts from rest (3 m/s later)
    assert torch.allclose(velocity[n - 1], velocity[n], atol=0.05)  # into the join as out of it
    acceleration = (velocity[1:] - velocity[:-1]).norm(dim=-1) * fps
    assert float(acceleration.max()) < 1.6 * 3.0 / (n / fps)  # smoothstep's peak, not a 90 m/s² jolt
    turn = rotation_angle_deg(out.joint_rotations[1:, 7], out.joint_rotations[:-1, 7]) * fps  # deg/s
    assert float(turn[n - 1]) == pytest.approx(float(turn[n]), rel=0.05)


def test_hold_and_heading():
    motion = _spin().with_hold(4)
    assert torch.equal(motion.joint_rotations[-1], motion.joint_rotations[-5])
    assert float(heading_angle(rot_z(torch.tensor(0.5)))) == pytest.approx(0.5, abs=1e-6)


def test_validation():
    with pytest.raises(ParameterError):
        Motion(torch.zeros(3, 30, 3, 3), torch.zeros(3, 3), 30.0, "bad")
    with pytest.raises(ParameterError):
        Motion(torch.eye(3).repeat(2, 31, 1, 1), torch.full((2, 3), float("nan")), 30.0, "nan")
