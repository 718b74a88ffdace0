"""L_phys of one teacher step (REFERENCE.md, "Energies"): the plain sum of HOOD's terms."""

from __future__ import annotations

import torch

from hyperbones.geometry.proximity import Nearest, face_planes, surface_points
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
