"""Canonical drape: let a garment settle on the A-pose body (quasi-static), and carry a
garment to another body shape before settling it there.

The drape looks for a local minimum of stretching + bending + gravity + body collision
+ friction (REFERENCE.md energies) over the free vertices, pinned ones held, by Newton's
method:

- Friction is lagged (IPC's way): each iteration measures slip from where it starts, so
  cloth resting on a sloped surface (shoulders, hips) slides only where the pull along
  the skin beats μ m g. Without it, an open shirt on sloping shoulders slides on for
  hundreds of iterations.

- Contact: the collision term's distance d_i is the exact signed distance to the skin:
  at every evaluation ``BodyProximity`` finds each vertex's nearest skin face and p_i, the
  closest point of that face, is computed again in double precision (Warp's float32 point
  makes the penalty's energy noisier than the last iterations gain, so the line search
  would stall short of rest), and
  ``collision_energy`` gets the plane through p_i normal to x_i − p_i (the distance's
  tangent plane; the nearest face's normal when x_i lies on the skin). The energy and its
  gradient so stay continuous when a vertex passes from one body face to the next, where
  the nearest face's own plane (HOOD's d) jumps.
- Newton step: the Hessian of every triangle (stretching) and hinge (bending) by autograd,
  with its eigenvalues replaced by their absolute values (so every step descends, and a
  buckling element keeps its curvature's size rather than none), summed into a sparse
  matrix and factorised by sparse LU in a nested-dissection order found once
  (``physics.sparse_hessian``). The collision penalty w·max(ε − d, 0)³ stiffens within micrometres, so a single linearisation lets vertices that reach the
  skin overshoot deep into it: the step minimises the quadratic cloth model plus the
  exact penalty along each vertex's frozen contact normal, with a second inner iteration
  (conjugate gradients preconditioned by the same factors) when the contact set changed.
- Line search on the true energy (nearest skin points found again at every trial): the
  step is halved until the energy decreases, or doubled while it keeps decreasing. A
  vertex whose step would carry it across a crease of the skin (its nearest skin point
  jumping to a surface facing the other way: the distance has a kink there that no step
  along one side's gradient descends) is held in place for that iteration. When no step
  decreases the energy, the Hessian is damped (Levenberg-Marquardt, ×100 at a time) and
  the step solved again.
- Stop, at rest, when either holds:
  - force balance: the 95th percentile over free vertices of |∇E_i| / (m_i g) is below
    ``force_tolerance`` (95 % of the vertices carry an out-of-balance force under that
    fraction of their own weight; the collision term is part of E, so a vertex resting on
    the skin counts as balanced when the skin's push carries it, and static friction takes
    up to μ m g of the pull along the skin);
  - the Newton step moves no vertex farther than ``step_tolerance`` (IPC's stopping rule:
    the configuration is that close to the minimum of its local model). Cloth that
    buckles under gravity (compressed StVK and bending are non-convex) can sit at such a
    point with stiff in-plane forces off balance by a fraction of a vertex's weight, and
    an energy that no longer changes in its sixth decimal.
  Otherwise it stops after ``max_iterations``, or when even the most damped step finds no
  decrease (the report says ``converged=False``).

A last projection moves any vertex still closer to the skin than half the margin to the
margin (resting vertices sit micrometres inside the margin, so normally none moves and the
result keeps the solver's force balance): the result never penetrates.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.linalg as sparse_linalg
import torch

from hyperbones.body.anny_body import Body
from hyperbones.garment.garment import Garment
from hyperbones.geometry.proximity import BodyProximity
from hyperbones.geometry.surface import closest_points_on_faces, face_planes, push_outside
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.energies import (FRICTION_COEFFICIENT, FRICTION_CONTACT_RADIUS, GRAVITY, bending_energy,
                                         collision_energy, friction_energy, gravity_energy, stretching_energy)
from hyperbones.physics.metrics import area_error_pct, edge_error_pct
from hyperbones.physics.sparse_hessian import SparseHessian, element_hessians

COLLISION_MARGIN = 2e-3  # ε of the collision energy (REFERENCE.md)
DRAPE_COLLISION_WEIGHT = 5e5  # HOOD's final weight: at rest nothing may pass through
FORCE_TOLERANCE = 0.1  # stop once p95 over free vertices of |∇E_i| / (m_i g) is below this,
STEP_TOLERANCE = 1e-4  # m: or once the Newton step moves no vertex farther than this (IPC's rule)
MAX_ITERATIONS = 800  # room for an open shirt that slides down a heavy body's shoulders before it rests
CONTACT_RANGE = 0.1  # m: vertices farther from the skin feel no collision
DRAPE_FRICTION_SMOOTHING = 1e-4  # m: friction's smooth norm turns linear past 0.1 mm of slip
MIN_DAMPING, MAX_DAMPING = 1e-6, 1e2  # Levenberg-Marquardt damping, relative to the Hessian's diagonal


@dataclass
class DrapeReport:
    """What the drape did: energies (J) before/after, errors (%) against the rest shape, and
    how close to rest it is: the force balance |∇E_i| / (m_i g) over free vertices (95th
    percentile and maximum) and the longest vertex move (m) of the Newton step solved at
    the returned state (NaN when force balance ended the drape before one was solved);
    ``converged``: either is below its tolerance."""

    energy_before: float
    energy_after: float
    edge_error_pct: float
    area_error_pct: float
    penetrating_before: int
    penetrating_after: int
    iterations: int  # Newton iterations
    force_ratio_p95: float
    force_ratio_max: float
    newton_step_max: float
    converged: bool
    rest_vertices: torch.Tensor | None = None  # (V,3) the rest shape used, when drape chose it


def _project_outside(points: torch.Tensor, proximity: BodyProximity, margin: float) -> tuple[torch.Tensor, int]:
    """Move points closer to the body than ``margin`` (or inside it) to ``margin`` outside."""
    nearest = proximity.query(points, max_distance=0.5)
    return push_outside(points, nearest, margin), int((nearest.found & (nearest.signed_distance < 0)).sum())


def _contact_planes(points: torch.Tensor, proximity: BodyProximity, body_vertices: torch.Tensor,
                    body_faces: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(V,3) nearest skin points and the unit outward normals of the distance's tangent
    planes there, along ±(point − nearest point); zero normals beyond ``CONTACT_RANGE``."""
    nearest = proximity.query(points.float(), max_distance=CONTACT_RANGE)
    on_skin = closest_points_on_faces(points, body_vertices, body_faces, nearest.face)  # float64, not Warp's float32
    offset = points - on_skin
    length = offset.norm(dim=-1, keepdim=True)
    sign = torch.where(nearest.signed_distance[:, None] < 0, -1.0, 1.0).to(points)
    _, face_normal = face_planes(body_vertices, body_faces, nearest.face)
    normal = torch.where(length > 1e-7, sign * offset / length.clamp_min(1e-30), face_normal)
    found = nearest.found[:, None]
    return torch.where(found, on_skin, torch.zeros_like(on_skin)), torch.where(found, normal, torch.zeros_like(normal))


def drape(garment: Garment, body: Body, max_iterations: int = MAX_ITERATIONS, force_tolerance: float = FORCE_TOLERANCE,
          step_tolerance: float = STEP_TOLERANCE, rest: ClothRest | None = None) -> tuple[Garment, DrapeReport]:
    """Settle ``garment`` on ``body``'s canonical A-pose (see the module docstring).

    Args:
        garment: the garment in canonical space; its current positions (pushed out of the
            skin) are also its rest shape unless ``rest`` is given (shape transfer passes the
            original pattern).
        max_iterations: Newton iterations at most.
        force_tolerance: stop once the 95th percentile over free vertices of |∇E_i| / (m_i g)
            is below this;
        step_tolerance: or once the Newton step moves no vertex farther than this (m).

    Returns:
        The draped garment (same topology, UVs, pins) and a report.
    """
    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    body_vertices = body.rest_vertices.double()
    x0, penetrating_before = _project_outside(garment.vertices, proximity, COLLISION_MARGIN)
    # Without an explicit pattern the rest shape is the fit itself, minus what poked
    # through the skin (MakeHuman fits made on another base body do, by a few mm).
    rest_vertices = x0 if rest is None else None
    rest = rest or ClothRest.from_mesh(x0.double(), garment.faces, garment.material)
    rest = rest.to(torch.float64)
    x = x0.double()
    free = torch.ones(len(x), dtype=torch.bool)
    free[garment.pinned] = False
    weight = rest.vertex_masses * GRAVITY
    element_energies = [(rest.faces, lambda points, faces: stretching_energy(points, replace(rest, faces=faces))),
                        (rest.hinges, lambda points, hinges: bending_energy(points, replace(rest, hinges=hinges)))]
    hessian = SparseHessian([rest.faces, rest.hinges], free, x)
    every_vertex = torch.arange(len(x))[:, None]

    def planes_for(positions):
        return _contact_planes(positions, proximity, body_vertices, body.faces)

    # Friction against the skin, lagged (as IPC does): each iteration's slip is measured
    # from where that iteration starts, so cloth on a sloped surface (shoulders, hips)
    # slides only where the pull along the skin beats μ m g, as Coulomb friction has it.
    lagged = {}

    def friction(positions):
        anchor, (points, normals) = lagged["x"], lagged["planes"]
        return friction_energy(positions, anchor, points, points, normals, rest, smoothing=DRAPE_FRICTION_SMOOTHING)

    def cloth_energy(positions):
        return (stretching_energy(positions, rest) + bending_energy(positions, rest) + gravity_energy(positions, rest)
                + friction(positions))

    def total_energy(positions, planes):
        return float(cloth_energy(positions) + collision_energy(positions, *planes, eps=COLLISION_MARGIN,
                                                                weight=DRAPE_COLLISION_WEIGHT))

    planes = planes_for(x)
    lagged.update(x=x, planes=planes)
    energy_before = total_energy(x, planes)
    iterations, newton_step_max = 0, float("inf")
    while True:
        lagged.update(x=x, planes=planes)
        positions = x.clone().requires_grad_(True)
        (cloth_gradient,) = torch.autograd.grad(cloth_energy(positions), positions)
        origin, normal = planes
        distance = ((x - origin) * normal).sum(-1)
        in_range = normal.square().sum(-1) > 0
        depth = torch.where(in_range, (COLLISION_MARGIN - distance).clamp_min(0.0), torch.zeros_like(distance))
        gradient = cloth_gradient - (3 * DRAPE_COLLISION_WEIGHT * depth.square())[:, None] * normal
        ratio = (_unbalanced_force(gradient, normal, in_range & (distance < FRICTION_CONTACT_RADIUS), weight)
                 / weight)[free]
        ratio_p95, ratio_max = (float(torch.quantile(ratio, 0.95)), float(ratio.max())) if len(ratio) else (0.0, 0.0)
        if ratio_p95 < force_tolerance or iterations >= max_iterations:
            newton_step_max = float("nan")  # no step solved at the returned state
            break
        cloth_hessian = hessian.matrix([element_hessians(x, elements, energy) for elements, energy in element_energies])
        cloth_hessian = cloth_hessian + hessian.vertex_blocks(element_hessians(x, every_vertex, lambda points, _: friction(points)))
        held, damping = torch.zeros(len(x), dtype=torch.bool), MIN_DAMPING
        step = _newton_step(x, cloth_gradient, distance, normal, in_range, hessian, cloth_hessian, held, damping)
        newton_step_max = float(step.norm(dim=-1).max())
        if newton_step_max < step_tolerance:
            break  # within step_tolerance of the minimum of the local model: at rest
        iterations += 1
        while True:
            moved, moved_planes, crossing = _line_search(x, planes, step, gradient, total_energy, planes_for)
            if moved is not None:
                break
            if crossing.any() and not held[crossing].all():
                held |= crossing  # solve again with the vertices at a crease held in place
            elif damping < MAX_DAMPING:
                damping *= 100  # Levenberg-Marquardt: a shorter step, closer to preconditioned descent
            else:
                break
            step = _newton_step(x, cloth_gradient, distance, normal, in_range, hessian, cloth_hessian, held, damping)
        if moved is None:  # no step decreases the energy: as settled as this solver gets
            break
        x, planes = moved, moved_planes
    x_final, penetrating_after = _project_outside(x.float(), proximity, COLLISION_MARGIN / 2)
    report = DrapeReport(
        energy_before=energy_before, energy_after=total_energy(x_final.double(), planes_for(x_final.double())),
        edge_error_pct=float(edge_error_pct(x_final[None].double(), rest)),
        area_error_pct=float(area_error_pct(x_final[None].double(), rest)),
        penetrating_before=penetrating_before, penetrating_after=penetrating_after, iterations=iterations,
        force_ratio_p95=ratio_p95, force_ratio_max=ratio_max, newton_step_max=newton_step_max,
        converged=bool(ratio_p95 < force_tolerance or newton_step_max < step_tolerance),
        rest_vertices=rest_vertices,
    )
    return garment.with_vertices(x_final), report


def _unbalanced_force(gradient: torch.Tensor, normal: torch.Tensor, touching: torch.Tensor,
                      weight: torch.Tensor) -> torch.Tensor:
    """(V,) the force friction cannot hold: |∇E_i|, except that a vertex touching the skin
    (normal n_i) has up to μ m_i g of the pull along the skin taken by static friction."""
    along = gradient - (gradient * normal).sum(-1, keepdim=True) * normal
    across = gradient - along
    held = along.norm(dim=-1).clamp_max(FRICTION_COEFFICIENT * weight)
    slipping = along * (1 - held / along.norm(dim=-1).clamp_min(1e-30))[:, None]
    return torch.where(touching, (across + slipping).norm(dim=-1), gradient.norm(dim=-1))


def _newton_step(x, cloth_gradient, distance, normal, in_range, hessian: SparseHessian, cloth_hessian,
                 held: torch.Tensor, damping: float, inner_iterations: int = 2) -> torch.Tensor:
    """(V,3) step s minimising g·s + ½ sᵀ(H + damping·diag H)s + w Σ max(ε − d_i − n_i·s_i, 0)³:
    the cloth's quadratic model plus the exact penalty along the frozen contact normals n_i.
    The damping (at least ``MIN_DAMPING``, which keeps free rigid motions solvable) grows
    while no step along the result decreases the energy."""
    weight = DRAPE_COLLISION_WEIGHT
    cloth = cloth_hessian + sparse.diags(damping * cloth_hessian.diagonal())
    if held.any():  # springs a million times the stiffest coordinate's hold these in place
        cloth = cloth + hessian.vertex_blocks(1e6 * cloth.diagonal().max() * held[:, None, None] * torch.eye(3))
    gradient = hessian.to_free(cloth_gradient)

    def depth_at(normal_offset):
        depth = (COLLISION_MARGIN - distance - normal_offset).clamp_min(0.0)
        return torch.where(in_range, depth, torch.zeros_like(depth))

    step, normal_step = np.zeros(hessian.size), torch.zeros_like(distance)  # s and n_i·s_i
    depth = depth_at(normal_step)
    touching = depth > 0
    factors = None
    for _ in range(inner_iterations):
        contact_stiffness = 6 * weight * depth[:, None, None] * normal[:, :, None] * normal[:, None, :]
        matrix = cloth + hessian.vertex_blocks(contact_stiffness)
        model_gradient = gradient + cloth @ step - hessian.to_free(3 * weight * depth.square()[:, None] * normal)
        if factors is None:
            factors = sparse_linalg.splu(matrix, permc_spec="NATURAL", diag_pivot_thresh=0.0,
                                         options={"SymmetricMode": True})
            direction = factors.solve(-model_gradient)
        else:  # only the contact stiffness changed: the factors precondition conjugate gradients
            preconditioner = sparse_linalg.LinearOperator(matrix.shape, factors.solve)
            direction, _ = sparse_linalg.cg(matrix, -model_gradient, M=preconditioner, rtol=1e-2, maxiter=10)
        # Backtrack on the model along the direction (quadratic cloth part + exact penalty).
        normal_direction = (hessian.from_free(direction) * normal).sum(-1)
        curved = cloth @ direction
        linear, quadratic = float(gradient @ direction + step @ curved), float(direction @ curved)
        slope = float(model_gradient @ direction)
        penalty = float(depth.pow(3).sum())

        def change(alpha):
            moved_penalty = float(depth_at(normal_step + alpha * normal_direction).pow(3).sum())
            return alpha * linear + 0.5 * alpha * alpha * quadratic + weight * (moved_penalty - penalty)

        alpha = 1.0
        while change(alpha) > 1e-4 * alpha * slope and alpha > 1e-6:
            alpha *= 0.5
        step, normal_step = step + alpha * direction, normal_step + alpha * normal_direction
        depth = depth_at(normal_step)
        if alpha == 1.0 and bool(((depth > 0) == touching).all()):
            break  # no vertex came into or out of contact: the first Newton step stands
    return hessian.from_free(step)


def _line_search(x, planes, step, gradient, total_energy, planes_for, longest: float = 8.0):
    """x + α·step with the true energy decreased (Armijo), α halved from 1 or, when 1 is
    accepted, doubled up to ``longest`` while the energy keeps falling; returns it, its
    contact planes, and the (V,) vertices held because their step crossed a crease. The
    first two are None when no α ≥ 1e-6 decreases the energy."""
    energy = total_energy(x, planes)

    def crossing(trial, trial_planes):
        """Vertices whose nearest skin point would jump to a surface facing the other way."""
        flips = (trial_planes[1] * planes[1]).sum(-1) < 0
        return flips & (planes[1].square().sum(-1) > 0) & (
            ((trial - trial_planes[0]) * trial_planes[1]).sum(-1) < COLLISION_MARGIN)

    alpha, best = 1.0, None
    held = torch.zeros(len(x), dtype=torch.bool)
    while alpha >= 1e-6:
        trial = x + alpha * step
        trial_planes = planes_for(trial)
        crossed = crossing(trial, trial_planes)
        if crossed.any():  # hold these for this iteration and try again
            held |= crossed
            step = torch.where(crossed[:, None], torch.zeros_like(step), step)
            continue
        trial_energy = total_energy(trial, trial_planes)
        if trial_energy <= energy + 1e-4 * alpha * float((gradient * step).sum()):
            best = (trial, trial_planes, trial_energy)
            break
        alpha *= 0.5
    if best is None:
        return None, None, held
    while alpha == 1.0 or 1.0 < alpha < longest:
        trial = x + 2 * alpha * step
        trial_planes = planes_for(trial)
        trial_energy = total_energy(trial, trial_planes)
        if crossing(trial, trial_planes).any() or trial_energy >= best[2]:
            break
        alpha, best = 2 * alpha, (trial, trial_planes, trial_energy)
    return best[0], best[1], held


def transfer(garment: Garment, source: Body, target: Body) -> Garment:
    """Carry a garment fitted to ``source`` onto ``target`` (a body of the same topology).

    Each garment vertex keeps its nearest point on the source skin (face + barycentric
    coordinates) and its signed offset along that face's normal; on the target the same
    skin point and offset give its new position. Relax the result with ``drape``.
    """
    proximity = BodyProximity(source.faces)
    proximity.update(source.rest_vertices)
    nearest = proximity.query(garment.vertices, max_distance=1.0)
    corners = target.faces[nearest.face.clamp_min(0)]
    tri = target.rest_vertices[corners]  # (V,3,3)
    point = (nearest.barycentric[..., None] * tri).sum(1)
    normal = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal = normal / normal.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    moved = point + nearest.signed_distance[:, None] * normal
    return garment.with_vertices(torch.where(nearest.found[:, None], moved, garment.vertices))
