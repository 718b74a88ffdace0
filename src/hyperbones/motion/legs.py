"""Assemble a full-body pose from a pelvis, foot placements and upper-body angles (legs by IK).

Used by the built-in clips: placing the feet and solving the legs analytically keeps a
planted foot exactly where it is and its sole exactly on the ground.
"""

from __future__ import annotations

import torch

from hyperbones.body.anny_body import Body
from hyperbones.body.skeleton import JOINT_INDEX as J
from hyperbones.body.skeleton import NUM_JOINTS
import math

import roma

from hyperbones.geometry.rotations import minimal_rotation, rot_x

SIDES = {"left": "Left", "right": "Right"}
# Bones that move rigidly with the forearm (the built-in clips do not pose the hands).
HAND_CHAIN = {
    "left": ("LeftForeArm", "LeftHand", "LThumb", "LeftFingerBase", "LeftHandFinger1"),
    "right": ("RightForeArm", "RightHand", "RThumb", "RightFingerBase", "RightHandFinger1"),
}
# Fraction of the full leg length a solved leg may use, so knees never lock straight
# (a straight knee makes the bend direction ill-defined and the pose jumpy).
MAX_REACH = 0.985
# Smallest hip-ankle distance as a fraction of the leg length: about 115-125 degrees of knee flexion.
MIN_FOLD = 0.55


def frame_from(direction: torch.Tensor, pole: torch.Tensor) -> torch.Tensor:
    """(...,3) main direction, (...,3) pole -> (...,3,3) orthonormal columns [d, p_perp, d x p_perp]."""
    d = direction / direction.norm(dim=-1, keepdim=True)
    p = pole - (pole * d).sum(-1, keepdim=True) * d
    p = p / p.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    return torch.stack([d, p, torch.linalg.cross(d, p)], dim=-1)


class LegRig:
    """The parts of one body's skeleton the pose builder needs (rest geometry, metres)."""

    def __init__(self, body: Body):
        rest = body.rest_joint_positions.float()
        self.rest = rest
        self.root = rest[0]
        self.hip_offset = {s: rest[J[f"{p}UpLeg"]] - rest[0] for s, p in SIDES.items()}
        self.thigh = {s: rest[J[f"{p}Leg"]] - rest[J[f"{p}UpLeg"]] for s, p in SIDES.items()}
        self.shin = {s: rest[J[f"{p}Foot"]] - rest[J[f"{p}Leg"]] for s, p in SIDES.items()}
        self.ankle = {s: rest[J[f"{p}Foot"]] for s, p in SIDES.items()}
        self.ball = {s: rest[J[f"{p}ToeBase"]] for s, p in SIDES.items()}
        # Heel pivot: on the ground, behind the ankle (the sole's back edge).
        self.heel = {}
        for s, p in SIDES.items():
            sole = body.rest_vertices[body.foot_vertex_indices[s]]
            self.heel[s] = torch.tensor([float(self.ankle[s][0]), float(sole[:, 1].max()), 0.0])
        self.leg_length = min(float(self.thigh[s].norm() + self.shin[s].norm()) for s in SIDES)
        self.upper_arm = {s: rest[J[f"{p}ForeArm"]] - rest[J[f"{p}Arm"]] for s, p in SIDES.items()}
        self.forearm = {s: rest[J[f"{p}Hand"]] - rest[J[f"{p}ForeArm"]] for s, p in SIDES.items()}

    def arm(self, side: str, swing: torch.Tensor, elbow: torch.Tensor, spread: float = 0.15):
        """Shoulder and elbow rotations (relative to the chest) of an arm hanging by the side.

        Anny's A-pose arm is raised 42 degrees with its forearm bent forward, so the pose is
        set by directions: the upper arm hangs (tilted out by ``spread``), swings forward by
        ``swing`` radians, the forearm bends forward by ``elbow`` radians; each bone takes
        the smallest rotation from its rest direction.

        Args:
            swing, elbow: (T,) radians.

        Returns:
            (T,3,3) shoulder rotation, (T,3,3) elbow rotation relative to the upper arm.
        """
        sign = 1.0 if side == "left" else -1.0
        hang = torch.tensor([sign * math.sin(spread), 0.0, -math.cos(spread)])
        upper_dir = rot_x(-swing) @ hang
        fore_dir = rot_x(-swing - elbow) @ hang
        shoulder = minimal_rotation(self.upper_arm[side].expand_as(upper_dir), upper_dir)
        fore = minimal_rotation(self.forearm[side].expand_as(fore_dir), fore_dir)
        return shoulder, shoulder.transpose(-1, -2) @ fore

    def solve(
        self,
        root: torch.Tensor,
        pelvis: torch.Tensor,
        ankles: dict[str, torch.Tensor],
        feet: dict[str, torch.Tensor],
        torso: torch.Tensor,
        head: torch.Tensor,
        arms: dict[str, tuple[torch.Tensor, torch.Tensor]],
        toes: dict[str, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Joint rotations (T,31,3,3) relative to the A-pose.

        Args:
            root: (T,3) Hips head.
            pelvis: (T,3,3) world rotation of the pelvis (Hips, hip joints).
            ankles: side -> (T,3) ankle (Foot joint head) targets.
            feet: side -> (T,3,3) world foot rotations (flat, facing forward = yaw only).
            torso: (T,3,3) extra rotation of the spine relative to the pelvis, spread over
                its three bones.
            head: (T,3,3) neck+head rotation relative to the upper spine.
            arms: side -> ((T,3,3) shoulder rotation of the upper arm relative to the chest,
                (T,3,3) elbow rotation relative to the upper arm).
            toes: side -> (T,3,3) world toe rotations (default: rigid with the foot).
        """
        toes = toes or feet
        num_frames = root.shape[0]
        rot = torch.eye(3).repeat(num_frames, NUM_JOINTS, 1, 1)
        rot[:, J["Hips"]] = rot[:, J["LHipJoint"]] = rot[:, J["RHipJoint"]] = pelvis
        third = roma.rotvec_to_rotmat(roma.rotmat_to_rotvec(torso) / 3)
        chest = pelvis
        for bone in ("LowerBack", "Spine", "Spine1"):
            chest = chest @ third
            rot[:, J[bone]] = chest
        rot[:, J["Neck"]] = rot[:, J["Neck1"]] = rot[:, J["Head"]] = chest @ head
        for side, prefix in SIDES.items():
            shoulder, elbow = arms[side]
            rot[:, J[f"{prefix}Shoulder"]] = chest
            upper = chest @ shoulder
            rot[:, J[f"{prefix}Arm"]] = upper
            lower = upper @ elbow
            for name in HAND_CHAIN[side]:
                rot[:, J[name]] = lower
            hip = root + pelvis @ self.hip_offset[side]
            thigh_rot, shin_rot = self._two_bone(side, hip, ankles[side], feet[side])
            rot[:, J[f"{prefix}UpLeg"]] = thigh_rot
            rot[:, J[f"{prefix}Leg"]] = shin_rot
            rot[:, J[f"{prefix}Foot"]] = feet[side]
            rot[:, J[f"{prefix}ToeBase"]] = toes[side]
        return rot

    def _two_bone(self, side: str, hip: torch.Tensor, ankle: torch.Tensor, foot: torch.Tensor):
        """Analytic two-bone IK: thigh and shin rotations putting the ankle at its target.

        The knee bends towards the foot's forward direction, so it follows the foot's yaw.
        """
        l1, l2 = float(self.thigh[side].norm()), float(self.shin[side].norm())
        reach = ankle - hip
        # Near the full fold (hip-ankle distance -> |l1 - l2|) the thigh direction swings
        # wildly; legs with a short thigh get there in a high-knee swing. Cap the fold.
        dist = reach.norm(dim=-1, keepdim=True).clamp(max(abs(l1 - l2) + 1e-4, MIN_FOLD * (l1 + l2)),
                                                      MAX_REACH * (l1 + l2))
        along = reach / reach.norm(dim=-1, keepdim=True)
        # The knee hinge axis is the foot's lateral axis: unlike "forward", it is never
        # parallel to the thigh (a high-knee run swing makes the thigh point forward).
        lateral = foot @ torch.tensor([1.0, 0.0, 0.0])
        cos_hip = (l1**2 + dist**2 - l2**2) / (2 * l1 * dist)
        sin_hip = (1 - cos_hip**2).clamp(min=0).sqrt()
        bend = torch.linalg.cross(along, lateral)
        bend = bend / bend.norm(dim=-1, keepdim=True).clamp(min=1e-9)
        knee = hip + l1 * (cos_hip * along + sin_hip * bend)
        ankle_reached = hip + dist * along
        rest_hinge = torch.tensor([1.0, 0.0, 0.0])
        thigh_rot = frame_from(knee - hip, lateral) @ frame_from(self.thigh[side], rest_hinge).T
        shin_rot = frame_from(ankle_reached - knee, lateral) @ frame_from(self.shin[side], rest_hinge).T
        return thigh_rot, shin_rot

    def max_root_height(self, root_xy: torch.Tensor, pelvis: torch.Tensor, ankles: dict[str, torch.Tensor]) -> torch.Tensor:
        """(T,) highest root z at which both ankles are still within reach."""
        limits = []
        for side in SIDES:
            offset = pelvis @ self.hip_offset[side]
            horizontal = (root_xy + offset[:, :2] - ankles[side][:, :2]).norm(dim=-1)
            reach = MAX_REACH * float(self.thigh[side].norm() + self.shin[side].norm()) - 1e-3
            vertical = (reach**2 - horizontal**2).clamp(min=0).sqrt()
            limits.append(ankles[side][:, 2] + vertical - offset[:, 2])
        return torch.stack(limits).amin(0)

    def planted_foot(self, side: str, ground_xy: torch.Tensor, yaw_rot: torch.Tensor, roll: torch.Tensor):
        """Ankle position and foot rotation of a foot on the ground, rolling on its heel or ball.

        Args:
            ground_xy: (T,2) where the flat foot's ankle projects on the ground.
            yaw_rot: (T,3,3) heading of the foot.
            roll: (T,) pitch in radians: > 0 lifts the heel (rolling on the ball), < 0 lifts
                the toes (rolling on the heel).

        Returns:
            (T,3) ankle, (T,3,3) foot rotation. The pivot stays put: the heel's ground
            point, or the toe-base joint (the toes stay flat; see ``solve(toes=...)``).
        """
        ankle_flat = torch.cat([ground_xy, self.ankle[side][2].expand(len(ground_xy), 1)], dim=-1)
        pivot_rest = torch.where(roll[:, None] > 0, self.ball[side], self.heel[side])
        pivot_local = pivot_rest - self.ankle[side]
        pivot = ankle_flat + (yaw_rot @ pivot_local.unsqueeze(-1)).squeeze(-1)
        foot = yaw_rot @ rot_x(roll)
        ankle = pivot + (foot @ (-pivot_local).unsqueeze(-1)).squeeze(-1)
        return ankle, foot


__all__ = ["LegRig", "frame_from"]
