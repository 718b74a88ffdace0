"""Virtual bones: a sparse set of control points that carries a garment between skeleton and cloth.

Skeleton -> bones: each bone sits on a garment vertex picked by farthest point sampling and
takes the body skinning weights of its nearest point on the skin (paper Sec. 3.1, after HOOD).
Bones -> garment: initial weights W0 = softmax(−d_geo/σ) over the bones, with d_geo the
geodesic distance along the garment (so the two sides of a thin panel do not couple through
the body). They stay dense (V,B): with σ = 5 cm and ~10 cm between bones a vertex's weight is
spread over many bones (docs/experiments/*-dense-bone-weights.md), and one
(V,B) @ (B,12) product per frame costs less than gathering them.

A bone's posed frame is rigid: the skinning blend Σ_k w_bk T_k of the joint transforms
gives its position (the blend applied to its rest position) and, through the Gram–Schmidt
of the blended 3×3's first two columns (the 6D representation), its rotation. The learnt
corrections of Module A act on that 6D rotation and on the position.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import roma
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.sampling import farthest_point_sampling

if TYPE_CHECKING:
    from hyperbones.body.anny_body import Body
    from hyperbones.garment.garment import Garment

NUM_BONES = 128
SIGMA = 0.05  # m, the geodesic fall-off of the initial weights (paper)


@dataclass
class VirtualBones:
    """The rig of one identity (garment on a body shape); all tensors on one device.

    rest_positions: (B,3) bone positions on the canonical garment.
    garment_vertex: (B,) int64 the garment vertex each bone sits on.
    joint_weights: (B,J) body skinning weights of each bone (rows sum to 1).
    log_weights: (V,B) log of the initial weights W0 (−inf for bones on another piece of cloth).
    """

    rest_positions: torch.Tensor
    garment_vertex: torch.Tensor
    joint_weights: torch.Tensor
    log_weights: torch.Tensor

    @classmethod
    def bind(cls, garment: Garment, body: Body, num_bones: int = NUM_BONES, sigma: float = SIGMA,
             rest_vertices: torch.Tensor | None = None) -> "VirtualBones":
        """Place ``num_bones`` bones on ``garment`` (canonical, fitted to ``body``).

        Each bone takes the skinning weights of the skin nearest its garment vertex on
        ``rest_vertices`` (V,3), the garment's rest shape on this body, when given; else
        where the vertex is on ``garment``. A drape can lay cloth on another body part than
        the one it was cut for (an open shirt's side panels on the arms of a heavy body):
        bound on the drape, those bones would swing with the arms; bound at the rest shape
        they stay with the torso. Training binds at the rest shape (its garments are
        undraped there).
        """
        # Binding needs Warp and potpourri3d; posing (the per-frame path) needs neither.
        from hyperbones.geometry.geodesic import geodesic_distances
        from hyperbones.geometry.proximity import BodyProximity

        if num_bones > garment.num_vertices:
            raise ParameterError(f"garment {garment.name!r}: {num_bones} virtual bones asked for, "
                                 f"but it has only {garment.num_vertices} vertices")
        if sigma <= 0:
            raise ParameterError(f"virtual bones: sigma must be > 0 m, got {sigma}")
        vertices = garment.vertices.cpu()
        if rest_vertices is not None and rest_vertices.shape != vertices.shape:
            raise ParameterError(f"garment {garment.name!r}: rest shape {tuple(rest_vertices.shape)} does not match "
                                 f"its vertices {tuple(vertices.shape)}")
        picked = farthest_point_sampling(vertices, num_bones)
        proximity = BodyProximity(body.faces.cpu())
        proximity.update(body.rest_vertices.cpu())
        anchors = vertices if rest_vertices is None else rest_vertices.detach().to("cpu", torch.float32)
        nearest = proximity.query(anchors[picked], max_distance=10.0)
        joint_weights = bone_joint_weights(nearest, body.faces.cpu(), body.skin_weights.cpu())
        distance = geodesic_distances(vertices, garment.faces.cpu(), picked).T  # (V,B)
        return cls(vertices[picked].clone(), picked, joint_weights, initial_log_weights(distance, vertices, picked, sigma))

    @property
    def num_bones(self) -> int:
        return self.rest_positions.shape[0]

    def to(self, device: torch.device | str) -> "VirtualBones":
        return VirtualBones(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def pose(self, skinning_transforms: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Posed bone frames from the skeleton's skinning transforms.

        Args:
            skinning_transforms: (...,J,4,4) rest -> posed joint transforms.

        Returns:
            rotations (...,B,3,3) and positions (...,B,3): bone b maps a rest point x to
            rotations_b (x − rest_positions_b) + positions_b.
        """
        return pose_bones(self.joint_weights, self.rest_positions, skinning_transforms)


def bone_joint_weights(nearest, body_faces: torch.Tensor, body_skin_weights: torch.Tensor) -> torch.Tensor:
    """(B,J) skinning weights of each bone from ``nearest`` (a ``Nearest`` of B bone anchors
    on the canonical body), interpolated over the face's corners; rows sum to 1."""
    corners = body_faces[nearest.face.clamp_min(0)]  # (B,3)
    weights = (nearest.barycentric[..., None] * body_skin_weights[corners]).sum(1)
    return weights / weights.sum(1, keepdim=True)


def initial_log_weights(distance: torch.Tensor, vertices: torch.Tensor, picked: torch.Tensor,
                        sigma: float = SIGMA) -> torch.Tensor:
    """(V,B) log W0 = log softmax(−d/σ) from ``distance`` (V,B) geodesic distances to the
    bones (inf: not on the same piece); ``vertices`` (V,3), ``picked`` (B,) the bones' vertices.

    A vertex on a piece without any bone (a small separate patch) falls back on straight-line
    distances rather than getting no weights at all.
    """
    distance = distance.float().clone()
    unreached = torch.isinf(distance).all(1)
    if unreached.any():
        distance[unreached] = torch.cdist(vertices[unreached], vertices[picked])
    logits = -distance / sigma
    return logits - torch.logsumexp(logits, dim=1, keepdim=True)


def pose_bones(joint_weights: torch.Tensor, rest_positions: torch.Tensor,
               skinning_transforms: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``VirtualBones.pose`` on explicit tensors, also batched over characters.

    joint_weights (...,B,J), rest_positions (...,B,3), skinning_transforms (...,J,4,4)
    -> rotations (...,B,3,3), positions (...,B,3).
    """
    rows = skinning_transforms[..., :3, :].flatten(-2)  # (...,J,12)
    blended = (joint_weights @ rows).unflatten(-1, (3, 4))  # (...,B,3,4)
    positions = (blended[..., :3] @ rest_positions[..., None]).squeeze(-1) + blended[..., 3]
    rotations = roma.special_gramschmidt(blended[..., :3, :2])
    return rotations, positions
