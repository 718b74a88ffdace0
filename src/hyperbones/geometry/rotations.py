"""Rotation helpers over batched tensors; conversions themselves come from roma."""

from __future__ import annotations

import roma
import torch


def axis_angle(axis: tuple[float, float, float], angle: torch.Tensor) -> torch.Tensor:
    """Rotation matrices about a fixed axis.

    Args:
        axis: a 3-vector (normalised here).
        angle: (...) angles in radians.

    Returns:
        (...,3,3) rotation matrices.
    """
    axis_t = torch.as_tensor(axis, dtype=angle.dtype, device=angle.device)
    axis_t = axis_t / axis_t.norm()
    return roma.rotvec_to_rotmat(angle.unsqueeze(-1) * axis_t)


def rot_x(angle: torch.Tensor) -> torch.Tensor:
    """(...) radians -> (...,3,3) rotation about +X."""
    return axis_angle((1.0, 0.0, 0.0), angle)


def rot_y(angle: torch.Tensor) -> torch.Tensor:
    """(...) radians -> (...,3,3) rotation about +Y."""
    return axis_angle((0.0, 1.0, 0.0), angle)


def rot_z(angle: torch.Tensor) -> torch.Tensor:
    """(...) radians -> (...,3,3) rotation about +Z (the up axis: a yaw)."""
    return axis_angle((0.0, 0.0, 1.0), angle)


def slerp_rotmat(r0: torch.Tensor, r1: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Spherical interpolation between rotation matrices.

    Args:
        r0, r1: (...,3,3) rotations (broadcastable).
        weight: (...) interpolation weights in [0,1]; 0 gives r0.

    Returns:
        (...,3,3) rotations on the shortest arc from r0 to r1.
    """
    q0 = roma.rotmat_to_unitquat(r0)
    q1 = roma.rotmat_to_unitquat(r1)
    q0, q1 = torch.broadcast_tensors(q0, q1)
    # roma's slerp takes one weight list for all pairs; do the shortest-arc slerp per element.
    dot = (q0 * q1).sum(-1, keepdim=True)
    q1 = torch.where(dot < 0, -q1, q1)
    dot = dot.abs().clamp(max=1.0)
    theta = torch.acos(dot)
    w = weight.unsqueeze(-1).to(q0.dtype)
    sin_theta = torch.sin(theta)
    small = sin_theta < 1e-6
    safe_sin = torch.where(small, torch.ones_like(sin_theta), sin_theta)
    a = torch.where(small, 1 - w, torch.sin((1 - w) * theta) / safe_sin)
    b = torch.where(small, w, torch.sin(w * theta) / safe_sin)
    q = a * q0 + b * q1
    return roma.unitquat_to_rotmat(q / q.norm(dim=-1, keepdim=True))


def rotation_angle_deg(r0: torch.Tensor, r1: torch.Tensor) -> torch.Tensor:
    """(...,3,3), (...,3,3) -> (...) geodesic angle between two rotations, degrees."""
    rel = r0.transpose(-1, -2) @ r1
    cos = ((rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1.0, 1.0)
    return torch.rad2deg(torch.acos(cos))


def minimal_rotation(src: torch.Tensor, dst: torch.Tensor) -> torch.Tensor:
    """Smallest rotation taking direction src onto direction dst.

    Args:
        src, dst: (...,3) non-zero vectors.

    Returns:
        (...,3,3) rotations R with R @ src/|src| = dst/|dst|.
    """
    a = src / src.norm(dim=-1, keepdim=True)
    b = dst / dst.norm(dim=-1, keepdim=True)
    axis = torch.linalg.cross(a, b)
    sin = axis.norm(dim=-1, keepdim=True)
    cos = (a * b).sum(-1, keepdim=True)
    angle = torch.atan2(sin, cos)
    # Antiparallel vectors: any axis orthogonal to a works; pick one stably.
    fallback = torch.linalg.cross(a, torch.tensor([1.0, 0.0, 0.0], dtype=a.dtype).expand_as(a))
    fallback = torch.where(fallback.norm(dim=-1, keepdim=True) < 1e-6,
                           torch.linalg.cross(a, torch.tensor([0.0, 1.0, 0.0], dtype=a.dtype).expand_as(a)),
                           fallback)
    axis = torch.where(sin < 1e-9, fallback, axis)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    return roma.rotvec_to_rotmat(axis * angle)


def rigid_inverse(transform: torch.Tensor) -> torch.Tensor:
    """(...,4,4) rigid transforms [R t; 0 1] -> their inverses [Rᵀ −Rᵀt; 0 1]: exact for a
    rotation R, cheaper than a general inverse, and expressible in ONNX (which has no
    matrix inverse)."""
    rotation_t = transform[..., :3, :3].transpose(-1, -2)
    translation = -(rotation_t @ transform[..., :3, 3:])
    top = torch.cat([rotation_t, translation], dim=-1)
    return torch.cat([top, transform[..., 3:, :]], dim=-2)
