"""Retargeting CMU clips onto Anny: fidelity of bone directions, time base, foot slip."""

import numpy as np
import pytest
import torch

from conftest import cmu_clip
from hyperbones.body.skeleton import AXIAL_SEGMENTS, JOINT_INDEX, LIMB_SEGMENTS
from hyperbones.motion.bvh import bvh_forward_kinematics, read_bvh
from hyperbones.motion.ground import foot_slip_per_step
from hyperbones.motion.load import capture_rate, load_motion

# Clip -> (what it is, real capture rate when the header is wrong).
CLIPS = {
    "02_01": "walk", "16_21": "walk", "16_27": "walk + turn", "69_53": "walk backwards + turn",
    "02_03": "run", "16_35": "run", "16_07": "forward jump", "143_06": "jumps in place",
    "05_06": "dance, pirouettes", "74_06": "kick", "111_10": "get up from chair", "01_01": "playground",
}
SOURCE_FPS = {"74_06": 60.0, "143_06": 60.0}  # as configs/teacher*.toml say
WALKS = ["02_01", "16_21", "16_27", "69_53"]


def _reference_positions(path, num_frames, source_fps):
    """BVH joint positions at times i/30 after the T-pose frame (linear between samples),
    mapped to Z up by hand: (x, y, z) -> (x, -z, y)."""
    clip = read_bvh(path)
    positions, _ = bvh_forward_kinematics(clip)
    positions = positions[1:]  # frame 0 is the T-pose
    t = np.arange(num_frames) * (source_fps or clip.fps) / 30.0
    lo = np.minimum(np.floor(t).astype(int), len(positions) - 1)
    hi = np.minimum(lo + 1, len(positions) - 1)
    w = (t - lo)[:, None, None]
    at_t = positions[lo] * (1 - w) + positions[hi] * w
    return torch.as_tensor(np.stack([at_t[..., 0], -at_t[..., 2], at_t[..., 1]], -1))


def _angles(ours, reference, segment):
    a, b = (JOINT_INDEX[j] for j in segment)
    d0 = (ours[:, b] - ours[:, a]).double()
    d1 = (reference[:, b] - reference[:, a]).double()
    cos = torch.nn.functional.cosine_similarity(d0, d1, dim=-1).clamp(-1, 1)
    return torch.rad2deg(torch.acos(cos))


@pytest.fixture(scope="module")
def retargeted(body):
    out = {}
    for name in CLIPS:
        path = cmu_clip(name)
        motion = load_motion(str(path), body, blend_in=0, source_fps=SOURCE_FPS.get(name))
        posed = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=False)
        out[name] = (path, motion, posed)
    return out


@pytest.mark.parametrize("name", list(CLIPS))
def test_bone_directions_follow_the_bvh(retargeted, name):
    path, motion, posed = retargeted[name]
    reference = _reference_positions(path, motion.num_frames, SOURCE_FPS.get(name))
    ours = posed.joint_positions
    for segment_name, segment in LIMB_SEGMENTS.items():
        angles = _angles(ours, reference, segment)
        assert angles.mean() < 5.0, (segment_name, float(angles.mean()))
        assert torch.quantile(angles, 0.95) < 12.0, (segment_name, float(torch.quantile(angles, 0.95)))
    for segment_name, segment in AXIAL_SEGMENTS.items():
        assert _angles(ours, reference, segment).mean() < 8.0, segment_name


def test_frame_i_is_bvh_time_i_over_fps(retargeted):
    """Arms are transferred exactly, so a time shift of even one BVH frame would show."""
    path, motion, posed = retargeted["02_01"]
    reference = _reference_positions(path, motion.num_frames, None)
    forearm = LIMB_SEGMENTS["left forearm"]
    assert _angles(posed.joint_positions, reference, forearm).max() < 0.05
    shifted = _angles(posed.joint_positions[1:], reference[:-1], forearm)
    assert shifted.mean() > 1.0


def test_root_path_scaled_to_leg_length_and_resampled(retargeted, body):
    path, motion, _ = retargeted["02_01"]
    clip = read_bvh(path)
    assert motion.fps == 30.0
    assert motion.num_frames == int((clip.num_frames - 2) / 4) + 1
    # The walk travels roughly as far as the actor did, scaled by the leg-length ratio.
    positions, _ = bvh_forward_kinematics(clip)
    actor_travel = np.linalg.norm((positions[-1, 0] - positions[1, 0])[[0, 2]]) * 0.056444
    travel = float((motion.root_translation[-1, :2] - motion.root_translation[0, :2]).norm())
    assert 0.6 * actor_travel < travel < 1.6 * actor_travel


@pytest.mark.parametrize("name", ["16_07", "143_06"])
def test_jumps_fall_at_about_one_g(retargeted, name):
    """At the top of each jump the body is in free fall: its root's vertical path curves at
    about g (scaled by the leg-length ratio) only when the clip plays at its real capture rate."""
    _, motion, _ = retargeted[name]
    height = motion.root_translation[:, 2].double().numpy()
    dt = 1.0 / motion.fps
    apexes = [i for i in range(3, len(height) - 3)
              if height[i] == height[i - 3:i + 4].max() and height[i] > np.median(height) + 0.1]
    assert apexes, "no jump found"
    for i in apexes:
        curvature = np.polyfit(np.arange(-2, 3) * dt, height[i - 2:i + 3], 2)[0] * 2
        assert -1.5 * 9.81 < curvature < -0.5 * 9.81, (i, curvature / 9.81)


def test_capture_rate_is_looked_up_by_clip_stem():
    rates = {"143_06": 60.0, "walk": 60.0}
    assert capture_rate("../shared/data/mocap/cmu/143_06.bvh", rates) == 60.0
    assert capture_rate("clips/16_21.bvh", rates) is None  # the header's rate
    assert capture_rate("walk", rates) is None  # built-in motions have no capture rate
    assert capture_rate("x/143_06.bvh", None) is None


@pytest.mark.parametrize("name", WALKS)
def test_foot_slip_under_2cm_per_step(retargeted, body, name):
    _, motion, posed = retargeted[name]
    steps = foot_slip_per_step(body, posed.skinning_transforms, motion.fps)
    assert len(steps) >= 4
    assert max(step["slip"] for step in steps) < 0.02


def test_feet_touch_the_ground(retargeted, body):
    from hyperbones.motion.ground import sole_heights

    for name in WALKS:
        _, motion, posed = retargeted[name]
        lowest = sole_heights(body, posed.skinning_transforms).amin(-1)
        assert lowest.min() > -0.02 and torch.quantile(lowest, 0.5) < 0.01, name


def test_blend_in_prepends_frames(body):
    path = cmu_clip("02_01")
    plain = load_motion(str(path), body, blend_in=0)
    blended = load_motion(str(path), body, blend_in=12)
    assert blended.num_frames == plain.num_frames + 12
    assert torch.allclose(blended.joint_rotations[12:], plain.joint_rotations)
