"""The Motion value: a pose per frame on the cmu_mb skeleton, plus its frame rate.

Poses follow the convention of ``hyperbones.body.skeleton``: per-joint world rotations
relative to the canonical A-pose and the world position of the Hips head. A Motion is
fitted to one body (its root path is scaled to that body's legs and its feet touch z = 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from hyperbones.body.skeleton import NUM_JOINTS
from hyperbones.errors import ParameterError
from hyperbones.geometry.rotations import rot_z, slerp_rotmat

DEFAULT_FPS = 30.0


@dataclass(frozen=True)
class Motion:
    """A posed skeleton over time.

    joint_rotations: (T,31,3,3) float32 world rotations relative to the A-pose.
    root_translation: (T,3) float32 world position of the Hips head, metres.
    fps: frames per second.
    name: a label (clip name or built-in name).
    """

    joint_rotations: torch.Tensor
    root_translation: torch.Tensor
    fps: float
    name: str

    def __post_init__(self) -> None:
        rot, root = self.joint_rotations, self.root_translation
        if rot.ndim != 4 or rot.shape[1:] != (NUM_JOINTS, 3, 3):
            raise ParameterError(f"motion {self.name!r}: joint_rotations must be (T,31,3,3), got {tuple(rot.shape)}")
        if root.shape != (rot.shape[0], 3):
            raise ParameterError(f"motion {self.name!r}: root_translation must be ({rot.shape[0]},3), got {tuple(root.shape)}")
        if rot.shape[0] < 1:
            raise ParameterError(f"motion {self.name!r} has no frames")
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ParameterError(f"motion {self.name!r}: fps must be positive, got {self.fps}")
        if not (torch.isfinite(rot).all() and torch.isfinite(root).all()):
            raise ParameterError(f"motion {self.name!r} contains NaN or infinite values")

    @property
    def num_frames(self) -> int:
        return self.joint_rotations.shape[0]

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    def slice(self, start: int, stop: int | None = None) -> "Motion":
        """Frames [start, stop)."""
        return replace(self, joint_rotations=self.joint_rotations[start:stop],
                       root_translation=self.root_translation[start:stop])

    def resample(self, fps: float = DEFAULT_FPS) -> "Motion":
        """Resample to ``fps``: frame i is the pose at time i/fps (slerp / lerp between samples)."""
        if fps == self.fps:
            return self
        return resample_poses(self.joint_rotations, self.root_translation, self.fps, fps, self.name)

    def with_hold(self, num_frames: int) -> "Motion":
        """Append ``num_frames`` copies of the last pose (a still hold at the end)."""
        if num_frames <= 0:
            return self
        rot = torch.cat([self.joint_rotations, self.joint_rotations[-1:].expand(num_frames, -1, -1, -1)])
        root = torch.cat([self.root_translation, self.root_translation[-1:].expand(num_frames, -1)])
        return replace(self, joint_rotations=rot, root_translation=root)

    def blend_in(self, num_frames: int, rest_root: torch.Tensor) -> "Motion":
        """Prepend a transition from the A-pose to the first frame over ``num_frames`` frames.

        The A-pose starts where the motion starts, with its heading, and with its root at the
        canonical height ``rest_root[2]``, so a garment draped on the canonical body can start
        from a rigid move of its drape. With 0 frames the motion is returned unchanged.
        """
        if num_frames <= 0:
            return self
        first_rot = self.joint_rotations[0]
        yaw = heading_angle(first_rot[0])
        start_rot = rot_z(yaw).expand(NUM_JOINTS, 3, 3)
        start_root = self.root_translation[0].clone()
        start_root[2] = rest_root[2]
        # Smoothstep weights: zero velocity at both ends, so nothing jerks at the joins.
        s = torch.arange(num_frames, dtype=torch.float32) / num_frames
        w = s * s * (3 - 2 * s)
        rot = slerp_rotmat(start_rot.unsqueeze(0), first_rot.unsqueeze(0), w[:, None].expand(-1, NUM_JOINTS))
        root = start_root + w[:, None] * (self.root_translation[0] - start_root)
        return replace(self, joint_rotations=torch.cat([rot, self.joint_rotations]),
                       root_translation=torch.cat([root, self.root_translation]))


def heading_angle(root_rotation: torch.Tensor) -> torch.Tensor:
    """(...,3,3) root rotation -> (...) yaw in radians of the facing direction (A-pose faces -Y: yaw 0)."""
    facing = root_rotation @ torch.tensor([0.0, -1.0, 0.0], dtype=root_rotation.dtype)
    return torch.atan2(facing[..., 0], -facing[..., 1])


def resample_poses(
    joint_rotations: torch.Tensor,
    root_translation: torch.Tensor,
    source_fps: float,
    target_fps: float,
    name: str,
) -> Motion:
    """Resample (N,31,3,3) rotations and (N,3) roots sampled at ``source_fps`` to ``target_fps``.

    Frame i of the result is the pose at time i/target_fps after the first source frame;
    the result stops at the last source sample.
    """
    num_source = joint_rotations.shape[0]
    duration = (num_source - 1) / source_fps
    num_target = int(math.floor(duration * target_fps + 1e-6)) + 1
    t = torch.arange(num_target, dtype=torch.float64) * (source_fps / target_fps)
    lo = t.floor().long().clamp(max=num_source - 1)
    hi = (lo + 1).clamp(max=num_source - 1)
    w = (t - lo.double()).float()
    rot = slerp_rotmat(joint_rotations[lo], joint_rotations[hi], w[:, None].expand(-1, NUM_JOINTS))
    root = root_translation[lo] + w[:, None] * (root_translation[hi] - root_translation[lo])
    return Motion(rot.float(), root.float(), float(target_fps), name)
