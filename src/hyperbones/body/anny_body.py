"""The Anny body (rig ``cmu_mb``): one model per process, a ``Body`` per shape.

Anny's rest pose is an A-pose with its origin near the pelvis. The project's canonical
body stands on the ground: the rest mesh is lifted so its lowest vertex is at z = 0.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import torch

from hyperbones.body.shape import PHENOTYPE_KEYS, BodyShape
from hyperbones.body.skeleton import JOINT_NAMES, JOINT_INDEX, NUM_JOINTS, forward_kinematics, skinning_transforms
from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.geometry.warp_setup import init_warp_quietly


@functools.lru_cache(maxsize=1)
def anny_model():
    """The process-wide Anny model (``rig="cmu_mb"``, float32).

    The first construction on a machine builds Anny's cache (kept in ``ANNY_CACHE_DIR``
    when set; faster with ``anny_loading``'s reader); later ones take a few seconds.
    Construct it once.
    """
    from hyperbones.body import anny_loading

    init_warp_quietly()
    anny_loading.install()
    import anny

    model = anny.Anny(rig="cmu_mb").to(torch.float32)
    if tuple(model.bone_labels) != JOINT_NAMES:
        raise RuntimeError(f"unexpected Anny cmu_mb joint names: {model.bone_labels}")
    return model


@dataclass
class PosedBody:
    """A body posed over T frames (all world coordinates, metres).

    joint_positions: (T,31,3) joint heads.
    joint_rotations: (T,31,3,3) world rotations relative to the A-pose.
    joint_world_transforms: (T,31,4,4) each joint's world frame (Anny's bone frame, Y along the bone).
    skinning_transforms: (T,31,4,4) rest -> posed transforms.
    vertices: (T,V,3) skinned mesh, or None when not requested.
    """

    joint_positions: torch.Tensor
    joint_rotations: torch.Tensor
    joint_world_transforms: torch.Tensor
    skinning_transforms: torch.Tensor
    vertices: torch.Tensor | None


class Body:
    """One Anny body shape with everything shape-specific precomputed.

    Attributes:
        shape: the phenotype values.
        rest_vertices: (V,3) canonical A-pose mesh standing on z = 0.
        faces: (F,3) triangles.
        skin_weights: (V,31) dense joint weights (rows sum to 1).
        rest_joint_positions: (31,3) canonical joint heads.
        rest_joint_tails: (31,3) canonical bone tails (leaf bones' ends).
        rest_joint_orientations: (31,3,3) canonical bone frames (Y along the bone).
        foot_vertex_indices: {"left","right"}: (n,) indices of sole vertices.
        ground_lift: (3,) translation from Anny's rest space to the canonical space.
    """

    joint_names = JOINT_NAMES

    def __init__(self, shape: BodyShape | None = None, device: str | torch.device = "cpu"):
        self.shape = shape or BodyShape()
        self.device = torch.device(device)
        model = anny_model()
        with torch.no_grad():
            out = model(None, phenotype_kwargs=self.shape.as_dict(), return_bone_ends=True)
        rest_vertices = out["rest_vertices"][0]
        lift = torch.tensor([0.0, 0.0, -float(rest_vertices[:, 2].min())])
        # Anny rest space -> canonical space (other Anny topologies of this shape use it too).
        self.ground_lift = lift.to(self.device)
        self.rest_vertices = (rest_vertices + lift).to(self.device)
        self.rest_joint_positions = (out["rest_bone_heads"][0] + lift).to(self.device)
        self.rest_joint_tails = (out["rest_bone_tails"][0] + lift).to(self.device)
        self.rest_joint_orientations = out["rest_bone_poses"][0, :, :3, :3].to(self.device)
        self.faces = model.faces.to(torch.int64).to(self.device)
        weights = torch.zeros(rest_vertices.shape[0], NUM_JOINTS)
        weights.scatter_add_(1, model.vertex_bone_indices.long(), model.vertex_bone_weights.float())
        self.skin_weights = (weights / weights.sum(1, keepdim=True)).to(self.device)
        self.foot_vertex_indices = {side: self._sole_vertices(side) for side in ("left", "right")}

    def _sole_vertices(self, side: str) -> torch.Tensor:
        """Vertices of one foot within 2 cm of the ground in the rest pose."""
        prefix = "Left" if side == "left" else "Right"
        foot = self.skin_weights[:, [JOINT_INDEX[f"{prefix}Foot"], JOINT_INDEX[f"{prefix}ToeBase"]]].sum(1)
        mask = (foot > 0.5) & (self.rest_vertices[:, 2] < 0.02)
        return torch.nonzero(mask).squeeze(1)

    @property
    def num_vertices(self) -> int:
        return self.rest_vertices.shape[0]

    def segment_length(self, parent: str, child: str) -> float:
        """Rest distance between two joint heads, metres."""
        delta = self.rest_joint_positions[JOINT_INDEX[child]] - self.rest_joint_positions[JOINT_INDEX[parent]]
        return float(delta.norm())

    @property
    def leg_length(self) -> float:
        """Mean over both sides of thigh + shin length (hip to ankle), metres."""
        sides = [("LeftUpLeg", "LeftLeg", "LeftFoot"), ("RightUpLeg", "RightLeg", "RightFoot")]
        return sum(self.segment_length(a, b) + self.segment_length(b, c) for a, b, c in sides) / 2

    @property
    def rest_root(self) -> torch.Tensor:
        """(3,) canonical position of the Hips head (the root translation of the A-pose)."""
        return self.rest_joint_positions[0]

    def pose(
        self,
        joint_rotations: torch.Tensor,
        root_translation: torch.Tensor,
        with_vertices: bool = True,
    ) -> PosedBody:
        """Pose the body over a batch of frames.

        Args:
            joint_rotations: (T,31,3,3) world rotations relative to the A-pose.
            root_translation: (T,3) world position of the Hips head.
            with_vertices: also skin the mesh (the costly part).

        Returns:
            PosedBody with all fields batched over T.
        """
        rotations = joint_rotations.to(self.device, torch.float32)
        root = root_translation.to(self.device, torch.float32)
        positions = forward_kinematics(self.rest_joint_positions, rotations, root)
        transforms = skinning_transforms(self.rest_joint_positions, rotations, positions)
        world = transforms.clone()
        world[..., :3, :3] = rotations @ self.rest_joint_orientations
        world[..., :3, 3] = positions
        vertices = None
        if with_vertices:
            vertices = linear_blend_skinning(self.rest_vertices, self.skin_weights, transforms)
        return PosedBody(positions, rotations, world, transforms, vertices)

    def skin_points(self, indices: torch.Tensor, skinning: torch.Tensor) -> torch.Tensor:
        """(n,) vertex indices, (T,31,4,4) skinning transforms -> (T,n,3) posed positions of those vertices."""
        return linear_blend_skinning(self.rest_vertices[indices], self.skin_weights[indices], skinning)


@functools.lru_cache(maxsize=16)
def body_for(shape: BodyShape) -> Body:
    """A cached Body per shape (building one runs the Anny model once)."""
    return Body(shape)


__all__ = ["Body", "BodyShape", "PosedBody", "anny_model", "body_for", "PHENOTYPE_KEYS"]
