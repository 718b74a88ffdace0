"""The cmu_mb skeleton (31 joints, named like the CMU mocap skeleton) and its kinematics.

Pose convention used throughout the project: a pose is given by
  * ``joint_rotations`` (...,31,3,3): each joint's *world* rotation relative to the
    canonical A-pose (identity everywhere = the A-pose), and
  * ``root_translation`` (...,3): the world position of the Hips joint head.
A child's head follows its parent's rigid motion, so bone lengths never change.
This is Anny's "world-orient" parameterisation with the rest orientation factored out,
which makes a pose independent of the body shape.
"""

from __future__ import annotations

import torch

JOINT_NAMES: tuple[str, ...] = (
    "Hips", "LHipJoint", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase",
    "LowerBack", "Spine", "Spine1",
    "LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand", "LThumb", "LeftFingerBase", "LeftHandFinger1",
    "Neck", "Neck1", "Head",
    "RightShoulder", "RightArm", "RightForeArm", "RightHand", "RThumb", "RightFingerBase", "RightHandFinger1",
    "RHipJoint", "RightUpLeg", "RightLeg", "RightFoot", "RightToeBase",
)
JOINT_PARENTS: tuple[int, ...] = (
    -1, 0, 1, 2, 3, 4, 0, 6, 7, 8, 9, 10, 11, 12, 12, 14, 8, 16, 17, 8, 19, 20, 21, 22, 22, 24,
    0, 26, 27, 28, 29,
)
NUM_JOINTS = len(JOINT_NAMES)
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINT_NAMES)}

# Limb segments (parent joint head -> child joint head) used by fidelity checks and retargeting.
LIMB_SEGMENTS: dict[str, tuple[str, str]] = {
    "left thigh": ("LeftUpLeg", "LeftLeg"),
    "right thigh": ("RightUpLeg", "RightLeg"),
    "left shin": ("LeftLeg", "LeftFoot"),
    "right shin": ("RightLeg", "RightFoot"),
    "left upper arm": ("LeftArm", "LeftForeArm"),
    "right upper arm": ("RightArm", "RightForeArm"),
    "left forearm": ("LeftForeArm", "LeftHand"),
    "right forearm": ("RightForeArm", "RightHand"),
}
AXIAL_SEGMENTS: dict[str, tuple[str, str]] = {
    "spine": ("LowerBack", "Neck"),
    "neck": ("Neck", "Head"),
}


def joint_index(name: str) -> int:
    """Index of a cmu_mb joint by name."""
    return JOINT_INDEX[name]


def forward_kinematics(
    rest_joint_positions: torch.Tensor,
    joint_rotations: torch.Tensor,
    root_translation: torch.Tensor,
) -> torch.Tensor:
    """World joint-head positions of a posed skeleton.

    Args:
        rest_joint_positions: (31,3) joint heads in the canonical A-pose, or (T,31,3): one
            skeleton per row (several characters posed at once).
        joint_rotations: (T,31,3,3) world rotations relative to the A-pose.
        root_translation: (T,3) world position of the Hips head.

    Returns:
        (T,31,3) joint heads: head_c = head_p + R_p (rest_c - rest_p).

    The rotations are world ones, so a head is the root plus its ancestors' rotated
    bone offsets: two batched products, no loop over the joints.
    """
    parents = _PARENTS.to(joint_rotations.device)
    offsets = rest_joint_positions - rest_joint_positions[..., parents, :]  # (...,31,3), root's is 0
    rotated = (joint_rotations[:, parents] @ offsets[..., None]).squeeze(-1)  # (T,31,3)
    ancestry = _ANCESTRY.to(device=joint_rotations.device, dtype=rotated.dtype)
    return root_translation[:, None] + ancestry @ rotated


def _ancestry() -> torch.Tensor:
    """(31,31) 1 where column joint k is the row joint itself or one of its ancestors below the root."""
    ancestry = torch.zeros(NUM_JOINTS, NUM_JOINTS)
    for joint in range(1, NUM_JOINTS):  # once, at import
        ancestor = joint
        while ancestor > 0:
            ancestry[joint, ancestor] = 1.0
            ancestor = JOINT_PARENTS[ancestor]
    return ancestry


_PARENTS = torch.tensor([0] + list(JOINT_PARENTS[1:]))  # the root is its own parent (offset 0)
_ANCESTRY = _ancestry()


def skinning_transforms(
    rest_joint_positions: torch.Tensor,
    joint_rotations: torch.Tensor,
    joint_positions: torch.Tensor,
) -> torch.Tensor:
    """Transforms that carry rest-pose points to the posed skeleton.

    Args:
        rest_joint_positions: (31,3) rest joint heads, or (T,31,3) one skeleton per row.
        joint_rotations: (T,31,3,3) world rotations relative to the A-pose.
        joint_positions: (T,31,3) posed joint heads (from forward_kinematics).

    Returns:
        (T,31,4,4) with x_posed = R_c (x_rest - rest_c) + head_c. Any other frames (virtual
        bones: rest (B,3), rotations (...,B,3,3), positions (...,B,3)) work the same way.
    """
    out = torch.zeros(*joint_rotations.shape[:-2], 4, 4, dtype=joint_rotations.dtype, device=joint_rotations.device)
    out[..., :3, :3] = joint_rotations
    out[..., :3, 3] = joint_positions - (joint_rotations @ rest_joint_positions.unsqueeze(-1)).squeeze(-1)
    out[..., 3, 3] = 1.0
    return out


def local_rotations(joint_rotations: torch.Tensor) -> torch.Tensor:
    """(T,31,3,3) world rotations -> (T,31,3,3) rotations relative to the parent's (root: world)."""
    parents = torch.tensor([0] + list(JOINT_PARENTS[1:]), device=joint_rotations.device)
    local = joint_rotations[:, parents].transpose(-1, -2) @ joint_rotations
    local[:, 0] = joint_rotations[:, 0]
    return local


def world_rotations(local: torch.Tensor) -> torch.Tensor:
    """(T,31,3,3) parent-relative rotations -> (T,31,3,3) world rotations (inverse of local_rotations)."""
    world = [local[:, 0]]
    for child in range(1, NUM_JOINTS):
        world.append(world[JOINT_PARENTS[child]] @ local[:, child])
    return torch.stack(world, dim=1)
