"""Canonical drape: let a garment settle on the A-pose body (quasi-static), and carry a
garment to another body shape before settling it there.

The drape minimises stretching + bending + gravity + body collision (REFERENCE.md
energies) over the free vertices, pinned ones held, with L-BFGS; nearest body faces are
found again between rounds (the collision term uses their planes). A last projection
puts any vertex still closer than the margin on the outside, so the result never
penetrates.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from hyperbones.body.anny_body import Body
from hyperbones.garment.garment import Garment
from hyperbones.geometry.proximity import BodyProximity, face_planes
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.energies import bending_energy, collision_energy, gravity_energy, stretching_energy
from hyperbones.physics.metrics import area_error_pct, edge_error_pct

COLLISION_MARGIN = 2e-3  # ε of the collision energy (REFERENCE.md)
DRAPE_COLLISION_WEIGHT = 5e5  # HOOD's final weight: at rest nothing may pass through


@dataclass
class DrapeReport:
    """What the drape did: energies (J) before/after, errors (%) against the rest shape."""

    energy_before: float
    energy_after: float
    edge_error_pct: float
    area_error_pct: float
    penetrating_before: int
    penetrating_after: int
    rounds: int
    rest_vertices: torch.Tensor | None = None  # (V,3) the rest shape used, when drape chose it


def _project_outside(points: torch.Tensor, proximity: BodyProximity, margin: float) -> tuple[torch.Tensor, int]:
    """Move points closer to the body than ``margin`` (or inside it) to ``margin`` outside."""
    nearest = proximity.query(points, max_distance=0.5)
    close = nearest.found & (nearest.signed_distance < margin)
    moved = points.clone()
    moved[close] = nearest.point[close] + margin * nearest.normal[close]
    return moved, int((nearest.found & (nearest.signed_distance < 0)).sum())


def drape(garment: Garment, body: Body, max_rounds: int = 12, iterations_per_round: int = 50,
          tolerance: float = 5e-4, rest: ClothRest | None = None) -> tuple[Garment, DrapeReport]:
    """Settle ``garment`` on ``body``'s canonical A-pose.

    Args:
        garment: the garment in canonical space; its current positions (pushed out of the
            skin) are also its rest shape unless ``rest`` is given (shape transfer passes the
            original pattern).
        max_rounds: outer rounds at most, each re-finding the nearest body faces; it stops
            once no vertex moves more than ``tolerance`` metres in a round (the energy is
            dominated by absolute gravity, so its relative change says little).
        iterations_per_round: L-BFGS iterations per round.

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

    def total_energy(positions: torch.Tensor, planes) -> torch.Tensor:
        origin, normal = planes
        return (stretching_energy(positions, rest) + bending_energy(positions, rest) + gravity_energy(positions, rest)
                + collision_energy(positions, origin, normal, eps=COLLISION_MARGIN, weight=DRAPE_COLLISION_WEIGHT))

    def planes_for(positions: torch.Tensor):
        nearest = proximity.query(positions.float(), max_distance=0.1)
        return face_planes(body_vertices, body.faces, nearest.face)

    energy_before = float(total_energy(x, planes_for(x)))
    rounds = 0
    while rounds < max_rounds:
        rounds += 1
        planes = planes_for(x)
        variable = x[free].clone().requires_grad_(True)
        optimizer = torch.optim.LBFGS([variable], lr=1.0, max_iter=iterations_per_round, history_size=20,
                                      line_search_fn="strong_wolfe", tolerance_grad=1e-9, tolerance_change=1e-12)

        def closure():
            optimizer.zero_grad()
            positions = x.clone()
            positions[free] = variable
            energy = total_energy(positions, planes)
            energy.backward()
            return energy

        optimizer.step(closure)
        with torch.no_grad():
            moved = float((variable.detach() - x[free]).norm(dim=-1).max()) if free.any() else 0.0
            x = x.clone()
            x[free] = variable.detach()
        if moved < tolerance:
            break
    x_final, penetrating_after = _project_outside(x.float(), proximity, COLLISION_MARGIN)
    energy_after = float(total_energy(x_final.double(), planes_for(x_final.double())))
    report = DrapeReport(
        energy_before=energy_before, energy_after=energy_after,
        edge_error_pct=float(edge_error_pct(x_final[None].double(), rest)),
        area_error_pct=float(area_error_pct(x_final[None].double(), rest)),
        penetrating_before=penetrating_before, penetrating_after=penetrating_after, rounds=rounds,
        rest_vertices=rest_vertices,
    )
    return garment.with_vertices(x_final), report


def transfer(garment: Garment, source: Body, target: Body) -> Garment:
    """Carry a garment fitted to ``source`` onto ``target`` (a body of the same topology).

    Each garment vertex keeps its nearest point on the source skin (face + barycentric
    coordinates) and its signed offset along that face's normal; on the target the same
    skin point and offset give its new position. Relax the result with ``drape``.
    """
    proximity = BodyProximity(source.faces)
    proximity.update(source.rest_vertices)
    nearest = proximity.query(garment.vertices, max_distance=1.0)
    corners = target.faces[nearest.face.clamp(min=0)]
    tri = target.rest_vertices[corners]  # (V,3,3)
    point = (nearest.barycentric[..., None] * tri).sum(1)
    normal = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal = normal / normal.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    moved = point + nearest.signed_distance[:, None] * normal
    return garment.with_vertices(torch.where(nearest.found[:, None], moved, garment.vertices))
