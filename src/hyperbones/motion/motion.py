"""The Motion value: a pose per frame on the cmu_mb skeleton, plus its frame rate.

Poses follow the convention of ``hyperbones.body.skeleton``: per-joint world rotations
relative to the canonical A-pose and the world position of the Hips head. A Motion is
fitted to one body (its root path is scaled to that body's legs and its feet touch z = 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import roma
import torch

from hyperbones.body.skeleton import NUM_JOINTS
from hyperbones.errors import ParameterError
from hyperbones.geometry.rotations import rot_z, slerp_rotmat

DEFAULT_FPS = 30.0
MAX_BLEND_EXTRAPOLATION = 0.6  # rad: how far a joint's first swing is carried back into the blend-in


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
        """Prepend a transition from the still A-pose into the first frame over ``num_frames`` frames.

        The A-pose takes the motion's first heading and the canonical root height
        ``rest_root[2]``, so a garment draped on the canonical body can start from a rigid
        move of its drape. The transition arrives at the first frame with the motion's own
        velocity, so nothing is kicked at the join (otherwise a clip that starts mid-run goes
        from standing to running speed in one frame, a jolt that outweighs the rest of the
        clip in per-frame inertia):

        - the root accelerates from rest along the first frame's velocity v0 with speed
          v0·w(s) (w the smoothstep, s from 0 to 1 over the transition), so the A-pose stands
          v0·D/2 behind the first frame's root (D the transition's duration);
        - each joint's rotation is slerped (weight w) from the A-pose to the first frame's
          rotation carried back along the joint's first angular velocity; that extrapolation
          is capped at ``MAX_BLEND_EXTRAPOLATION`` radians, so a fast-swinging limb keeps part
          of its velocity jump rather than turning through a half circle before the join.

        With 0 frames the motion is returned unchanged.
        """
        if num_frames <= 0:
            return self
        duration = num_frames / self.fps
        first_rot, first_root = self.joint_rotations[0], self.root_translation[0]
        if self.num_frames > 1:
            root_velocity = (self.root_translation[1] - first_root) * self.fps  # (3,) m/s
            spin = roma.rotmat_to_rotvec(self.joint_rotations[1] @ first_rot.transpose(-1, -2)) * self.fps  # (31,3)
        else:
            root_velocity, spin = torch.zeros(3), torch.zeros(NUM_JOINTS, 3)
        speed = spin.norm(dim=-1, keepdim=True)
        spin = spin * (2 * MAX_BLEND_EXTRAPOLATION / (duration * speed).clamp_min(2 * MAX_BLEND_EXTRAPOLATION))
        s = torch.arange(num_frames, dtype=torch.float32) / num_frames  # (n,)
        w = s * s * (3 - 2 * s)  # smoothstep: zero velocity at both ends
        ramp = (s ** 3 - s ** 4 / 2)[:, None]  # ∫_0^s w: distance covered at speed v0·w, ½ at s = 1
        start_rot = rot_z(heading_angle(first_rot[0])).expand(NUM_JOINTS, 3, 3)
        carried_back = roma.rotvec_to_rotmat(spin * duration * (ramp[:, :, None] - 0.5)) @ first_rot  # (n,31,3,3)
        rot = slerp_rotmat(start_rot.unsqueeze(0), carried_back, w[:, None].expand(-1, NUM_JOINTS))
        arrival = first_root - root_velocity * duration / 2  # where the root would be without the run-up
        start_root = arrival.clone()
        start_root[2] = rest_root[2]
        root = start_root + w[:, None] * (arrival - start_root) + root_velocity * duration * ramp
        return replace(self, joint_rotations=torch.cat([rot, self.joint_rotations]),
                       root_translation=torch.cat([root, self.root_translation]))


def heading_angle(root_rotation: torch.Tensor) -> torch.Tensor:
    """(...,3,3) root rotation -> (...) yaw in radians of the facing direction (A-pose faces -Y: yaw 0)."""
    facing = root_rotation @ torch.tensor([0.0, -1.0, 0.0], dtype=root_rotation.dtype, device=root_rotation.device)
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
