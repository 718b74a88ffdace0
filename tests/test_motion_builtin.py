"""Built-in clips: smooth, deterministic, parametrised, feet on the ground."""

import pytest
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.rotations import rotation_angle_deg
from hyperbones.motion.builtin import BUILTINS, builtin_motion
from hyperbones.motion.ground import sole_points, still_frames

REQUIRED = {"walk", "run", "jump", "turn", "idle", "arm-swing", "sit"}


@pytest.fixture(scope="module")
def clips(body):
    return {name: builtin_motion(name, body, hold=1.0) for name in BUILTINS}


def test_required_clips_exist():
    assert REQUIRED <= set(BUILTINS)


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_no_rotation_jumps(clips, name):
    steps = rotation_angle_deg(clips[name].joint_rotations[1:], clips[name].joint_rotations[:-1])
    assert steps.max() < 30.0


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_feet_on_the_ground(clips, body, name):
    """No sole sinks more than 1 cm; a foot that stands still (>= 3 frames) touches the ground."""
    motion = clips[name]
    posed = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=False)
    for side, points in sole_points(body, posed.skinning_transforms).items():
        lowest = points[..., 2].amin(-1)
        assert lowest.min() > -0.01, (side, float(lowest.min()))
        standing = still_frames(points, motion.fps)
        assert standing.any(), side
        assert lowest[standing].max() < 0.01, (side, float(lowest[standing].max()))


def test_deterministic_and_parametrised(body):
    a = builtin_motion("walk", body, speed=1.0, duration=3.0)
    b = builtin_motion("walk", body, speed=1.0, duration=3.0)
    assert torch.equal(a.joint_rotations, b.joint_rotations) and torch.equal(a.root_translation, b.root_translation)
    fast = builtin_motion("walk", body, speed=1.6, duration=3.0)
    travel = lambda m: float((m.root_translation[-1, :2] - m.root_translation[0, :2]).norm())  # noqa: E731
    assert travel(fast) > 1.3 * travel(a)
    assert builtin_motion("idle", body, duration=2.0).num_frames == 61


def test_hold_is_still_and_ends_standing(body, clips):
    motion = builtin_motion("run", body, duration=3.0, hold=2.0)
    assert motion.num_frames == 91 + 60
    assert torch.equal(motion.joint_rotations[-1], motion.joint_rotations[-60])
    # The motion itself comes to rest before the hold: the last moving second slows down.
    speed = (motion.root_translation[1:, :2] - motion.root_translation[:-1, :2]).norm(dim=-1) * 30
    assert speed[85:90].max() < 0.5 < speed[40:50].max()


def test_turn_spins_and_jump_leaves_the_ground(clips):
    from hyperbones.motion.motion import heading_angle

    yaw = heading_angle(clips["turn"].joint_rotations[:, 0])
    total = torch.diff(yaw).remainder(2 * torch.pi)
    total = torch.where(total > torch.pi, total - 2 * torch.pi, total).sum().abs()
    assert total > torch.pi  # more than half a turn
    root_z = clips["jump"].root_translation[:, 2]
    assert root_z.max() - root_z[0] > 0.15


def test_bad_parameters(body):
    with pytest.raises(ParameterError, match="unknown built-in motion"):
        builtin_motion("moonwalk", body)
    with pytest.raises(ParameterError, match="--speed"):
        builtin_motion("run", body, speed=-1.0)
    with pytest.raises(ParameterError, match="--duration"):
        builtin_motion("walk", body, duration=0.1)


@pytest.mark.parametrize("shape", ["age=0,height=0", "gender=1,weight=1,height=0", "gender=0,height=1,muscle=1,proportions=1"])
def test_any_body_shape_moves_cleanly(shape):
    """Clips scale with the leg length, so an infant or a tall body is as clean as the default one."""
    from hyperbones.body import BodyShape, body_for

    body = body_for(BodyShape.parse(shape))
    for name in BUILTINS:
        motion = builtin_motion(name, body, hold=0.5)
        steps = rotation_angle_deg(motion.joint_rotations[1:], motion.joint_rotations[:-1])
        assert steps.max() < 30.0, name
        posed = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=False)
        for points in sole_points(body, posed.skinning_transforms).values():
            heights = points[..., 2].amin(-1)
            assert heights.min() > -0.01, name
            still = still_frames(points, motion.fps)
            assert heights[still].max() < 0.01, name
