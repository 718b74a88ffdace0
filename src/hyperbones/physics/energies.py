"""HOOD's cloth energies as pure, differentiable, batched functions (REFERENCE.md, "Energies").

Every function takes garment positions with any leading batch shape, ``(...,V,3)`` in metres,
and returns energies in joules with that batch shape ``(...)``. Rest quantities come from a
``ClothRest`` (``hyperbones.physics.cloth``). Its material may hold per-face and per-hinge
tensors instead of floats (a ``BatchMaterial``: several garments in one mesh), so material
parameters must only ever multiply per-element terms. Gravity acts along −Z.
"""

from __future__ import annotations

import torch

from hyperbones.physics.cloth import ClothRest, dihedral_angles

GRAVITY = 9.81
"""m/s², along −Z (REFERENCE.md, "Material")."""

COLLISION_EPSILON = 2e-3
"""Collision margin ε in metres (REFERENCE.md, "Collision")."""

COLLISION_WEIGHT = 5e5
"""Collision weight w: HOOD ramps it from 5e3 to 5e5 during training; this is the final value."""

FRICTION_COEFFICIENT = 0.5
"""μ_f (REFERENCE.md, "Friction")."""

FRICTION_CONTACT_RADIUS = 3e-3
"""A vertex rubs on the body when within this distance (m) of it at both frames ("a few mm")."""

FRICTION_SMOOTHING = 1e-6
"""δ (m) of the smooth norm sqrt(|s|²+δ²)−δ used for the slip: differentiable at zero slip."""


def stretching_energy(x: torch.Tensor, rest: ClothRest) -> torch.Tensor:
    """StVK membrane energy (REFERENCE.md, "Stretching"): (...,V,3) -> (...).

    Per face F = D_s D_m⁻¹ (3×2) with D_s = [x0−x2, x1−x2]; G = ½(FᵀF − I);
    S = μG + ½λ tr(G) I; E = Σ_f A_f⁰ h tr(SᵀG) = Σ_f A_f⁰ h (μ tr(G²) + ½λ tr(G)²).
    """
    material = rest.material
    corners = x[..., rest.faces, :]  # (...,F,3,3)
    ds = torch.stack([corners[..., 0, :] - corners[..., 2, :], corners[..., 1, :] - corners[..., 2, :]], dim=-1)
    deformation = ds @ rest.dm_inv.to(x)  # (...,F,3,2)
    green = 0.5 * (deformation.transpose(-1, -2) @ deformation - torch.eye(2, dtype=x.dtype, device=x.device))
    trace = green[..., 0, 0] + green[..., 1, 1]
    # tr(SᵀG) with S symmetric: μ Σ G_ab² + ½λ tr(G)².
    density = material.lame_mu * green.square().sum(dim=(-1, -2)) + 0.5 * material.lame_lambda * trace.square()
    return (rest.face_areas.to(x) * material.thickness * density).sum(-1)


def bending_energy(x: torch.Tensor, rest: ClothRest) -> torch.Tensor:
    """Discrete-shell bending over interior edges (REFERENCE.md, "Bending"): (...,V,3) -> (...).

    E = Σ_e k_b l_e² / (4(A1⁰+A2⁰)) · (θ − θ⁰)² / 2 with θ = atan2(ê·(n1×n2), n1·n2), l_e
    the rest edge length and A⁰ the rest areas of the two faces. θ⁰ = 0 (HOOD's flat rest),
    not ``rest.hinge_rest_angles``. Non-manifold edges are not hinges (``ClothRest``).
    The angle's gradient is finite at flat and degenerate hinges (see ``dihedral_angles``).
    """
    if rest.hinges.shape[0] == 0:
        return x.new_zeros(x.shape[:-2])
    angles = dihedral_angles(x, rest.hinges)
    lengths, areas = rest.hinge_lengths.to(x), rest.hinge_areas.to(x)
    stiffness = rest.material.bending * lengths.square() / (4.0 * areas.sum(-1)).clamp_min(1e-30)
    return (stiffness * angles.square() / 2.0).sum(-1)


def gravity_energy(x: torch.Tensor, rest: ClothRest, g: float = GRAVITY) -> torch.Tensor:
    """Gravitational potential Σ_i m_i g z_i (REFERENCE.md, "Gravity"): (...,V,3) -> (...).

    Absolute height energy: its zero is z = 0, so fix the origin before comparing runs.
    """
    return (rest.vertex_masses.to(x) * g * x[..., 2]).sum(-1)


def inertia_energy(
    x_next: torch.Tensor, x_curr: torch.Tensor, x_prev: torch.Tensor, rest: ClothRest, dt: float = 1.0 / 30.0
) -> torch.Tensor:
    """Inertia with per-frame displacements (REFERENCE.md, "Inertia"): 3 × (...,V,3) -> (...).

    E = Σ_i m_i ‖x_next − (x_curr + (x_curr − x_prev))‖² / (2 dt²): zero for uniform motion.
    """
    return _inertia(x_next - (2.0 * x_curr - x_prev), rest, dt)


def inertia_energy_velocity(
    x_next: torch.Tensor, x_curr: torch.Tensor, v_curr: torch.Tensor, rest: ClothRest, dt: float = 1.0 / 30.0
) -> torch.Tensor:
    """Inertia with an explicit velocity state (REFERENCE.md, "Inertia"): 3 × (...,V,3) -> (...).

    E = Σ_i m_i ‖x_next − (x_curr + v_curr dt)‖² / (2 dt²), ``v_curr`` in m/s.
    """
    return _inertia(x_next - (x_curr + v_curr * dt), rest, dt)


def _inertia(offset: torch.Tensor, rest: ClothRest, dt: float) -> torch.Tensor:
    return (rest.vertex_masses.to(offset) * offset.square().sum(-1)).sum(-1) / (2.0 * dt * dt)


def collision_energy(
    x: torch.Tensor,
    nearest_points: torch.Tensor,
    nearest_normals: torch.Tensor,
    eps: float = COLLISION_EPSILON,
    weight: float = COLLISION_WEIGHT,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """Body-collision penalty (REFERENCE.md, "Collision"): (...,V,3) -> (...).

    E = w Σ_i max(ε − d_i, 0)³ with d_i = (x_i − c_i)·n_i. The caller finds each vertex's
    nearest body face at frame t without gradients (``BodyProximity.query``) and passes c_i,
    n_i, a point on and the unit outward normal of that face posed at frame t+1, (...,V,3)
    (e.g. ``Nearest.point`` at t+1 or the face's vertex 0). d_i is then the signed distance
    to the face's plane, differentiable in x only.

    Vertices whose normal is zero (``BodyProximity`` gives that to points with no face in
    range) or where ``mask`` (...,V) is False are skipped.
    """
    distance = ((x - nearest_points) * nearest_normals).sum(-1)
    active = nearest_normals.square().sum(-1) > 0
    if mask is not None:
        active = active & mask
    penetration = torch.where(active, (eps - distance).clamp_min(0.0), torch.zeros_like(distance))
    return weight * penetration.pow(3).sum(-1)


def friction_energy(
    x_next: torch.Tensor,
    x_curr: torch.Tensor,
    body_next_points: torch.Tensor,
    body_curr_points: torch.Tensor,
    normals: torch.Tensor,
    rest: ClothRest,
    mu: float = FRICTION_COEFFICIENT,
    g: float = GRAVITY,
    contact_radius: float = FRICTION_CONTACT_RADIUS,
    smoothing: float = FRICTION_SMOOTHING,
) -> torch.Tensor:
    """Body friction (REFERENCE.md, "Friction"): (...,V,3) garment and body points -> (...).

    body_*_points: (...,V,3) the point on the body each vertex is attached to at frames t
    and t+1 (the same body-surface point, posed at both frames); normals: (...,V,3) unit
    outward body normals at t+1. A vertex is in contact when its plane distance
    (x − body point)·n is below ``contact_radius`` at both frames (decided without
    gradients). Its slip s = (x_next − x_curr) − (body_next − body_curr), projected on the
    tangent plane, costs E = μ m_i g |s_t|, where |·| is the smooth norm
    sqrt(|s|² + δ²) − δ (δ = ``smoothing``): it has a gradient at zero slip, where the true
    norm has none, and differs from |s| by less than δ.
    """
    with torch.no_grad():
        gap_next = ((x_next - body_next_points) * normals).sum(-1)
        gap_curr = ((x_curr - body_curr_points) * normals).sum(-1)
        contact = (gap_next < contact_radius) & (gap_curr < contact_radius) & (normals.square().sum(-1) > 0)
    slip = (x_next - x_curr) - (body_next_points - body_curr_points)
    tangential = slip - (slip * normals).sum(-1, keepdim=True) * normals
    slip_norm = (tangential.square().sum(-1) + smoothing * smoothing).sqrt() - smoothing
    per_vertex = mu * rest.vertex_masses.to(x_next) * g * slip_norm
    return torch.where(contact, per_vertex, torch.zeros_like(per_vertex)).sum(-1)
