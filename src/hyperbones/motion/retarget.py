"""Retarget a CMU BVH clip onto the Anny cmu_mb skeleton by world-orientation transfer.

Steps (DESIGN.md, "Motion: real mocap"):
1. BVH axes (Y up, actor facing +Z at frame 0) -> project axes (Z up, facing -Y):
   (x, y, z) -> (x, -z, y). Units x 0.056444 -> metres.
2. Frame 0 (the T-pose frame the CMU conversion adds) is dropped.
3. Every Anny joint takes the BVH joint's world rotation. Limb bones additionally carry a
   rest alignment (Anny's A-pose bone direction -> the BVH's T-pose one), so that each
   limb points exactly where the actor's did; torso bones transfer the rotation alone,
   because the two skeletons place their pelvis and spine joints differently.
4. The root path is scaled by the ratio of the body's leg length to the actor's, then
   lifted so the feet touch z = 0, and everything is resampled to the target frame rate.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import torch

from hyperbones.body.anny_body import Body
from hyperbones.body.skeleton import JOINT_INDEX, JOINT_NAMES, JOINT_PARENTS
from hyperbones.errors import ParameterError
from hyperbones.geometry.rotations import minimal_rotation
from hyperbones.motion.bvh import BvhClip, bvh_forward_kinematics, read_bvh
from hyperbones.motion.footlock import lock_feet
from hyperbones.motion.ground import sole_points
from hyperbones.motion.motion import DEFAULT_FPS, Motion, resample_poses

BVH_UNIT_METRES = 0.056444
# BVH (x, y, z) -> project (x, -z, y): a proper rotation (det +1).
BVH_TO_WORLD = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]], dtype=torch.float64)

# Limb bones and the joint their direction points to, on both skeletons.
_LIMB_TARGETS = {f"{side}{bone}": f"{side}{target}" for side in ("Left", "Right")
                 for bone, target in (("UpLeg", "Leg"), ("Leg", "Foot"), ("Arm", "ForeArm"),
                                      ("ForeArm", "Hand"), ("Hand", "HandFinger1"))}
# Bone -> (the Anny joint its direction points to, the BVH rest segment it is aligned with).
# Anny's Spine1 has no BVH counterpart (the BVH's Spine1 head coincides with its Neck), so
# it follows the BVH's Spine segment. Feet are not aligned: both rest poses stand
# flat-footed, while the ankle -> toe-base line dips 19 degrees on Anny and 10 on the BVH,
# so aligning that line would lift Anny's toes off the ground.
ALIGNED_BONES: dict[str, tuple[str, tuple[str, str]]] = {
    **{bone: (target, (bone, target)) for bone, target in _LIMB_TARGETS.items()},
    "LowerBack": ("Spine", ("LowerBack", "Spine")),
    "Spine": ("Spine1", ("Spine", "Spine1")),
    "Spine1": ("Neck", ("Spine", "Spine1")),
    "Neck": ("Neck1", ("Neck", "Neck1")),
    "Neck1": ("Head", ("Neck1", "Head")),
}
# Above this root speed a clip is probably captured at a lower rate than its header says.
IMPLAUSIBLE_ROOT_SPEED = 9.0


def _bvh_rest_positions(clip: BvhClip) -> torch.Tensor:
    """(31,3) joint positions in the BVH's zero-rotation (T-pose) layout, BVH units and axes."""
    offsets = torch.as_tensor(clip.offsets, dtype=torch.float64)
    rest = [offsets[0] * 0]
    for child in range(1, len(JOINT_NAMES)):
        rest.append(rest[JOINT_PARENTS[child]] + offsets[child])
    return torch.stack(rest)


def rest_alignment(body: Body, clip: BvhClip) -> torch.Tensor:
    """(31,3,3) rotations taking each Anny rest bone onto the BVH rest bone.

    Feet and toes keep their world rest orientation (identity: flat on the ground in both
    rests); other bones without a counterpart (pelvis, clavicles, fingers) inherit their
    parent's alignment, so they stay rigid relative to it.
    """
    bvh_rest = BVH_TO_WORLD @ _bvh_rest_positions(clip).T
    bvh_rest = bvh_rest.T
    anny_rest = body.rest_joint_positions.double()
    align = [torch.eye(3, dtype=torch.float64)]
    for joint in range(1, len(JOINT_NAMES)):
        name = JOINT_NAMES[joint]
        if name in ALIGNED_BONES:
            anny_target, (start, end) = ALIGNED_BONES[name]
            bvh_dir = bvh_rest[JOINT_INDEX[end]] - bvh_rest[JOINT_INDEX[start]]
            anny_dir = anny_rest[JOINT_INDEX[anny_target]] - anny_rest[joint]
            if bvh_dir.norm() < 1e-9:
                align.append(align[JOINT_PARENTS[joint]])
            else:
                align.append(minimal_rotation(anny_dir, bvh_dir))
        elif name.endswith(("Foot", "ToeBase")):
            align.append(torch.eye(3, dtype=torch.float64))
        else:
            align.append(align[JOINT_PARENTS[joint]])
    return torch.stack(align)


def bvh_leg_length_m(clip: BvhClip) -> float:
    """Mean thigh + shin length of the actor, metres."""
    offsets = torch.as_tensor(clip.offsets, dtype=torch.float64)
    total = sum(offsets[JOINT_INDEX[f"{s}Leg"]].norm() + offsets[JOINT_INDEX[f"{s}Foot"]].norm() for s in ("Left", "Right"))
    return float(total / 2 * BVH_UNIT_METRES)


def retarget_bvh(
    path: str | Path,
    body: Body,
    fps: float = DEFAULT_FPS,
    source_fps: float | None = None,
    lock_feet_in_stance: bool = True,
) -> Motion:
    """Read a CMU BVH file and retarget it onto ``body``.

    Args:
        path: the .bvh file (CMU MotionBuilder-friendly layout).
        body: the target body.
        fps: frame rate of the result; frame i is the BVH pose at time i/fps after the
            T-pose frame.
        source_fps: the rate the clip was captured at, when its header is wrong (some CMU
            trials were captured at 60 fps but say 120).
        lock_feet_in_stance: hold planted feet in place (``hyperbones.motion.footlock``).

    Returns:
        The Motion, named after the file.
    """
    clip = read_bvh(path)
    if source_fps is not None and source_fps <= 0:
        raise ParameterError(f"--source-fps must be positive, got {source_fps}")
    clip_fps = source_fps or clip.fps
    positions, rotations = bvh_forward_kinematics(clip)
    positions = torch.as_tensor(positions[1:], dtype=torch.float64)  # drop the T-pose frame
    rotations = torch.as_tensor(rotations[1:], dtype=torch.float64)

    world_rot = BVH_TO_WORLD @ rotations @ BVH_TO_WORLD.T
    joint_rotations = world_rot @ rest_alignment(body, clip)
    scale = BVH_UNIT_METRES * body.leg_length / bvh_leg_length_m(clip)
    # The legs hang from the hip joints, which the two skeletons place differently relative
    # to their Hips joint (the BVH's is ~10 cm higher); tracking the hip-joint centre keeps
    # the feet where the actor's were.
    hips = [JOINT_INDEX["LeftUpLeg"], JOINT_INDEX["RightUpLeg"]]
    bvh_hip_centre = (positions[:, hips].mean(1) @ BVH_TO_WORLD.T) * scale
    anny_rest = body.rest_joint_positions.double()
    anny_hip_offset = anny_rest[hips].mean(0) - anny_rest[0]
    root = bvh_hip_centre - (joint_rotations[:, 0] @ anny_hip_offset)

    motion = resample_poses(joint_rotations.float(), root.float(), clip_fps, fps, Path(path).stem)
    motion = place_on_ground(motion, body)
    if lock_feet_in_stance:
        motion = lock_feet(motion, body)
    _warn_if_too_fast(motion, path, clip_fps)
    return motion


def place_on_ground(
    motion: Motion,
    body: Body,
    stance_speed: float = 0.3,
    smoothing_seconds: float = 0.4,
) -> Motion:
    """Lift a motion so that planted feet rest on z = 0.

    Capture floors are rarely level (the planted foot of a CMU walk can rise 5 cm over a
    clip), so one constant offset leaves feet floating or sinking. The ground height is
    instead estimated over time from the frames where a foot is planted (its sole moves
    slower than ``stance_speed`` m/s), interpolated across the others (a jump keeps its
    flight) and smoothed with a Gaussian of ``smoothing_seconds``; the root is lowered by it.
    """
    posed = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=False)
    points = sole_points(body, posed.skinning_transforms)
    heights, planted = [], []
    for side_points in points.values():
        centre = side_points[..., :2].mean(1)
        speed = (centre[1:] - centre[:-1]).norm(dim=-1) * motion.fps
        speed = torch.cat([speed[:1], speed]) if len(speed) else torch.zeros(1)
        heights.append(side_points[..., 2].amin(-1))
        planted.append(speed < stance_speed)
    heights, planted = torch.stack(heights, -1), torch.stack(planted, -1)  # (T,2)
    # Where both feet are planted the lower one is on the ground.
    ground = torch.where(planted, heights, torch.full_like(heights, float("inf"))).amin(-1)
    known = torch.isfinite(ground)
    if known.sum() < 2:
        ground = torch.full_like(ground, float(torch.quantile(heights.amin(-1), 0.1)))
    else:
        t = torch.arange(len(ground), dtype=torch.float64)
        ground = torch.from_numpy(np.interp(t.numpy(), t[known].numpy(), ground[known].double().numpy()))
        ground = _gaussian_smooth(ground, smoothing_seconds * motion.fps).float()
    root = motion.root_translation.clone()
    root[:, 2] -= ground
    return Motion(motion.joint_rotations, root, motion.fps, motion.name)


def _gaussian_smooth(signal: torch.Tensor, sigma_frames: float) -> torch.Tensor:
    """(T,) -> (T,) Gaussian low-pass with edge padding."""
    radius = int(3 * sigma_frames)
    if radius < 1 or len(signal) < 2:
        return signal
    x = torch.arange(-radius, radius + 1, dtype=signal.dtype)
    kernel = torch.exp(-0.5 * (x / sigma_frames) ** 2)
    kernel /= kernel.sum()
    padded = torch.cat([signal[:1].expand(radius), signal, signal[-1:].expand(radius)])
    return torch.nn.functional.conv1d(padded[None, None], kernel[None, None])[0, 0]


def _warn_if_too_fast(motion: Motion, path, clip_fps: float) -> None:
    if motion.num_frames < 3:
        return
    speed = (motion.root_translation[1:, :2] - motion.root_translation[:-1, :2]).norm(dim=-1) * motion.fps
    fast = float(torch.quantile(speed, 0.9))
    if fast > IMPLAUSIBLE_ROOT_SPEED:
        warnings.warn(
            f"{path}: the root moves at {fast:.1f} m/s at {clip_fps:g} fps; if the clip was captured "
            f"at a lower rate than its header says, pass --source-fps (e.g. {clip_fps / 2:g})",
            stacklevel=2,
        )
