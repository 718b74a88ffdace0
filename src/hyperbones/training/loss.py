"""L_phys of one teacher step (REFERENCE.md, "Energies"): the plain sum of HOOD's terms."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from hyperbones.geometry.diffusion import diffuse
from hyperbones.geometry.surface import Nearest, face_planes, surface_points
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.energies import (
    COLLISION_EPSILON,
    GRAVITY,
    bending_energy,
    collision_energy,
    friction_energy,
    inertia_energy,
    stretching_energy,
)


def collision_weight_at(step: int, start: float, end: float, ramp_steps: int) -> float:
    """HOOD's ramp of the collision weight: geometric from ``start`` to ``end`` over ``ramp_steps``."""
    if ramp_steps <= 0 or step >= ramp_steps:
        return end
    return start * (end / start) ** (step / ramp_steps)


def physics_terms(positions_next: torch.Tensor, positions: torch.Tensor, velocities: torch.Tensor, rest: ClothRest,
                  nearest: Nearest, body_now: torch.Tensor, body_next: torch.Tensor, body_faces: torch.Tensor,
                  collision_weight: float, dt: float) -> dict[str, torch.Tensor]:
    """Each energy (J) of the step t -> t+1, evaluated on x(t+1).

    positions_next: (V,3) the prediction; positions, velocities: (V,3) the state at t
    (per-step displacement); nearest: faces found for x(t) on the body at t; body_*: (Vb,3).
    Gravity is counted from x(t) (the same gradient as the absolute energy, small numbers).
    """
    origin, normal = face_planes(body_next, body_faces, nearest.face)
    follow_now = surface_points(body_now, body_faces, nearest.face, nearest.barycentric)
    follow_next = surface_points(body_next, body_faces, nearest.face, nearest.barycentric)
    masses = rest.vertex_masses.to(positions_next)
    return {
        "stretching": stretching_energy(positions_next, rest),
        "bending": bending_energy(positions_next, rest),
        "gravity": (masses * GRAVITY * (positions_next[:, 2] - positions[:, 2])).sum(),
        "inertia": inertia_energy(positions_next, positions, positions - velocities, rest, dt=dt),
        "collision": collision_energy(positions_next, origin, normal, eps=COLLISION_EPSILON, weight=collision_weight),
        "friction": friction_energy(positions_next, positions, follow_next, follow_now, normal, rest),
    }


def edge_length_error(positions: torch.Tensor, target: torch.Tensor, edges: torch.Tensor,
                      frame_sizes: Sequence[int]) -> torch.Tensor:
    """() mean over frames of the mean over a frame's edges of (|p_i − p_j| − |t_i − t_j|)² (m²).

    positions, target: (V,3) the frames' vertices one after another (``frame_sizes`` each);
    edges: (E,2) in that numbering, each within one frame. An edge's frame is its first vertex's.
    """
    def lengths(points: torch.Tensor) -> torch.Tensor:
        return (points[edges[:, 0]] - points[edges[:, 1]]).norm(dim=-1)

    sizes = torch.tensor(list(frame_sizes), device=positions.device)
    frame_of_vertex = torch.arange(len(sizes), device=positions.device).repeat_interleave(sizes)
    frame_of_edge = frame_of_vertex[edges[:, 0]]
    edges_per_frame = torch.bincount(frame_of_edge, minlength=len(sizes)).to(positions.dtype)  # only read where > 0
    share = 1.0 / (len(sizes) * edges_per_frame[frame_of_edge])
    return ((lengths(positions) - lengths(target)).square() * share).sum()


def laplacian(values: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """(V,C) per-vertex values, (E,2) undirected edges -> (V,C) value minus the mean of its
    neighbours (one full ``diffuse`` step takes each vertex to that mean)."""
    return values - diffuse(values, edges, torch.ones_like(values[:, :1]), steps=1)


def runtime_terms(positions: torch.Tensor, target: torch.Tensor, edges: torch.Tensor, rest: ClothRest,
                  nearest: Nearest, body: torch.Tensor, body_faces: torch.Tensor, collision_weight: float,
                  config, frame_sizes: Sequence[int] | None = None) -> dict[str, torch.Tensor]:
    """Module A's loss (paper Sec. 3.5): L_3D against C plus physics on A's output, the mean
    over F frames, each of one garment on its body.

    positions: (V,3) A's garments, the F frames' one after another (``frame_sizes``: their
    vertex counts; None: one frame); target: (V,3) C's (no gradient); edges: (E,2) the
    garments' edges in that numbering; rest: their joined rest state
    (``episode_batch.joined_rest``); nearest: body faces found for ``positions`` on ``body``
    (Vb,3), the F bodies laid one after another, whose faces are ``body_faces``;
    config: ``JointConfig``.

    L_3D = MSE + λ_lap·L_lap + λ_interp·L_interp (+ λ_edge·L_edge where ``edge_weight`` is
    set), each a mean over a frame's vertices (L_edge: its edges) with lengths scaled by
    ``position_scale``. L_lap is taken on the error A − C: it punishes the per-vertex ripples
    that sparse bones leave, and is zero when A matches C (on A's positions alone it would
    also punish every fold C makes). L_interp = mean max(0, ε − d)² with d the signed
    distance to the nearest body face's plane. The energies, sums over a garment, are
    averaged over the frames.
    """
    sizes = [positions.shape[0]] if frame_sizes is None else list(frame_sizes)
    if sum(sizes) != positions.shape[0]:
        raise ValueError(f"frame_sizes {sizes} do not add up to the {positions.shape[0]} positions")
    frames = len(sizes)
    # Each vertex's share of a per-frame mean, averaged over the frames: 1/(F·V_f).
    share = torch.tensor([1.0 / (frames * size) for size in sizes], dtype=positions.dtype,
                         device=positions.device).repeat_interleave(torch.tensor(sizes, device=positions.device))
    scale = config.position_scale
    error = positions - target.detach()
    origin, normal = face_planes(body, body_faces, nearest.face)
    distance = ((positions - origin) * normal).sum(-1)
    touching = normal.square().sum(-1) > 0
    inside = (config.interpenetration_epsilon - distance).clamp_min(0) * touching
    terms = {
        "a_mse": (error.square().sum(-1) * share).sum() * scale,
        "a_laplacian": config.laplacian_weight * (laplacian(error, edges).square().sum(-1) * share).sum() * scale,
        "a_interpenetration": config.interpenetration_weight * (inside.square() * share).sum() * scale,
    }
    if config.edge_weight:
        edge_error = edge_length_error(positions, target.detach(), edges, sizes)
        terms["a_edge_length"] = config.edge_weight * edge_error * scale
    if config.physics_on_runtime:
        terms["a_stretching"] = stretching_energy(positions, rest) / frames
        terms["a_bending"] = bending_energy(positions, rest) / frames
        terms["a_collision"] = collision_energy(positions, origin, normal, eps=COLLISION_EPSILON,
                                                weight=collision_weight) / frames
    return terms
