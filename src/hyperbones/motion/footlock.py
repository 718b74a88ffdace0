"""Plant the feet of a retargeted motion: cancel sole sliding during stance with leg IK.

Faithful rotation transfer keeps every limb pointing where the actor's did, but the
actor's feet slid a little during stance (joint-centre noise, a body of other
proportions), and a sliding sole is the most visible artefact of a retarget. Here each
stance's slide is measured on the sole vertices that touch the ground, the ankle target
is shifted back by the accumulated slide, and thigh and shin are re-solved by two-bone IK
in the knee's current bend plane. A sole below the floor is raised onto it the same way.
Feet keep their world rotation; the correction fades out over the following swing.
"""

from __future__ import annotations

import torch

from hyperbones.body.anny_body import Body
from hyperbones.body.skeleton import JOINT_INDEX as J
from hyperbones.geometry.rotations import minimal_rotation
from hyperbones.motion.ground import planted, sole_points, stance_intervals
from hyperbones.motion.motion import Motion

SIDES = {"left": "Left", "right": "Right"}
# Largest lift of a sunken sole (metres): the ground estimate is good to a few cm on
# walks; beyond that (a cartwheel) the estimate, not the foot, is what is wrong.
MAX_RAISE = 0.03


def _corrections(slide: torch.Tensor, stances: list[tuple[int, int]], num_frames: int) -> torch.Tensor:
    """(T-1,2) slides, stance runs -> (T,2) horizontal ankle corrections (fading out between stances)."""
    correction = torch.zeros(num_frames, 2)
    for start, stop in stances:
        correction[start + 1:stop] = -torch.cumsum(slide[start:stop - 1], 0)
    # Between a stance's end and the next stance's start, ease the correction back to zero.
    ends = [stop for _, stop in stances]
    starts = [start for start, _ in stances[1:]] + [num_frames]
    for end, next_start in zip(ends, starts):
        if end >= num_frames or next_start <= end:
            continue
        u = torch.arange(1, next_start - end + 1, dtype=torch.float32) / (next_start - end + 1)
        fade = 1 - u * u * (3 - 2 * u)
        correction[end:next_start] = correction[end - 1] * fade[:, None]
    return correction


def lock_feet(motion: Motion, body: Body, contact_height: float = 0.025, max_speed: float = 1.0,
              min_frames: int = 3) -> Motion:
    """Return ``motion`` with its planted feet held in place (see the module docstring).

    Args:
        contact_height: a sole vertex lower than this touches the ground (metres).
        max_speed: a foot whose sole centre moves faster than this (m/s) is swinging, not planted.
    """
    posed = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=False)
    rotations = motion.joint_rotations.clone()
    for side, points in sole_points(body, posed.skinning_transforms).items():
        prefix = SIDES[side]
        slide, stance = planted(points, motion.fps, contact_height, max_speed)
        stances = stance_intervals(stance, min_frames)
        if not stances:
            continue
        shift = _corrections(slide, stances, motion.num_frames)
        # A sole below the floor (the smoothed ground estimate can dip under a stance) is
        # raised until it touches (at most MAX_RAISE); continuous in time because the sole height is.
        raise_by = (-points[..., 2].amin(-1)).clamp(min=0, max=MAX_RAISE)
        hip = posed.joint_positions[:, J[f"{prefix}UpLeg"]]
        knee = posed.joint_positions[:, J[f"{prefix}Leg"]]
        ankle = posed.joint_positions[:, J[f"{prefix}Foot"]]
        target = ankle + torch.cat([shift, raise_by[:, None]], dim=-1)
        new_knee = _solve_knee(hip, knee, ankle, target,
                               body.segment_length(f"{prefix}UpLeg", f"{prefix}Leg"),
                               body.segment_length(f"{prefix}Leg", f"{prefix}Foot"))
        thigh_fix = minimal_rotation(knee - hip, new_knee - hip)
        shin_fix = minimal_rotation(ankle - knee, target - new_knee)
        rotations[:, J[f"{prefix}UpLeg"]] = thigh_fix @ rotations[:, J[f"{prefix}UpLeg"]]
        rotations[:, J[f"{prefix}Leg"]] = shin_fix @ rotations[:, J[f"{prefix}Leg"]]
    return Motion(rotations, motion.root_translation, motion.fps, motion.name)


def _solve_knee(hip, knee, ankle, target, thigh: float, shin: float) -> torch.Tensor:
    """(T,3) knee position reaching ``target`` (clamped to reach), bending in the current knee plane."""
    reach = target - hip
    dist = reach.norm(dim=-1, keepdim=True).clamp(abs(thigh - shin) + 1e-4, 0.999 * (thigh + shin))
    along = reach / reach.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    # The bend direction: the current knee's offset from the hip-ankle line.
    current = ankle - hip
    current = current / current.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    bend = (knee - hip) - ((knee - hip) * current).sum(-1, keepdim=True) * current
    bend = bend - (bend * along).sum(-1, keepdim=True) * along
    bend = bend / bend.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    cos_hip = (thigh**2 + dist**2 - shin**2) / (2 * thigh * dist)
    sin_hip = (1 - cos_hip**2).clamp(min=0).sqrt()
    return hip + thigh * (cos_hip * along + sin_hip * bend)
