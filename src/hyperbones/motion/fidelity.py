"""How faithfully a retargeted motion follows its BVH: per-frame bone-direction errors."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from hyperbones.body.anny_body import Body
from hyperbones.body.skeleton import AXIAL_SEGMENTS, JOINT_INDEX, LIMB_SEGMENTS
from hyperbones.motion.bvh import BvhClip, bvh_forward_kinematics
from hyperbones.motion.ground import foot_slip_per_step
from hyperbones.motion.motion import Motion
from hyperbones.motion.retarget import BVH_TO_WORLD, BVH_UNIT_METRES


@dataclass
class SegmentError:
    """Angle statistics (degrees) of one segment's direction over all frames."""

    name: str
    mean: float
    p95: float
    max: float


def bvh_positions_at(clip: BvhClip, num_frames: int, fps: float, source_fps: float | None = None) -> torch.Tensor:
    """BVH joint positions (num_frames,31,3), project axes, metres (unscaled), at times i/fps after the T-pose frame."""
    positions, _ = bvh_forward_kinematics(clip)
    positions = torch.as_tensor(positions[1:], dtype=torch.float64) @ BVH_TO_WORLD.T * BVH_UNIT_METRES
    t = torch.arange(num_frames, dtype=torch.float64) * ((source_fps or clip.fps) / fps)
    lo = t.floor().long().clamp(max=positions.shape[0] - 1)
    hi = (lo + 1).clamp(max=positions.shape[0] - 1)
    w = (t - lo.double())[:, None, None]
    return positions[lo] * (1 - w) + positions[hi] * w


def direction_errors(ours: torch.Tensor, reference: torch.Tensor) -> dict[str, torch.Tensor]:
    """Per-frame angle (degrees) between segment directions.

    Args:
        ours, reference: (T,31,3) joint positions on the same time base.

    Returns:
        segment name -> (T,) angles, for the limb and axial segments of ``hyperbones.body.skeleton``.
    """
    out = {}
    for name, (a, b) in {**LIMB_SEGMENTS, **AXIAL_SEGMENTS}.items():
        d0 = ours[:, JOINT_INDEX[b]] - ours[:, JOINT_INDEX[a]]
        d1 = reference[:, JOINT_INDEX[b]] - reference[:, JOINT_INDEX[a]]
        cos = torch.nn.functional.cosine_similarity(d0.double(), d1.double(), dim=-1).clamp(-1, 1)
        out[name] = torch.rad2deg(torch.acos(cos))
    return out


def retarget_report(motion: Motion, body: Body, clip: BvhClip, source_fps: float | None = None) -> dict:
    """Fidelity of a retargeted motion (made with blend-in 0) against its BVH.

    Returns a dict with per-segment ``SegmentError``s, the limb aggregate (mean, p95),
    and the steps with their foot slip (see ``foot_slip_per_step``).
    """
    posed = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=False)
    reference = bvh_positions_at(clip, motion.num_frames, motion.fps, source_fps)
    errors = direction_errors(posed.joint_positions, reference)
    segments = {
        name: SegmentError(name, float(e.mean()), float(torch.quantile(e, 0.95)), float(e.max()))
        for name, e in errors.items()
    }
    limbs = torch.cat([errors[name] for name in LIMB_SEGMENTS])
    return {
        "segments": segments,
        "limb_mean": float(limbs.mean()),
        "limb_p95": float(torch.quantile(limbs, 0.95)),
        "steps": foot_slip_per_step(body, posed.skinning_transforms, motion.fps),
    }
