"""Metrics of a simulated garment sequence, as REFERENCE.md defines them."""

from __future__ import annotations

import torch

from hyperbones.geometry.proximity import BodyProximity
from hyperbones.geometry.search import signed_distances_along
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.metrics import (
    HOOD_COLLISION_THRESHOLD, area_error_pct, collision_pct, detached_pct, edge_error_pct, enclosed_area, mean_energies,
)


RUNAWAY_SPEED = 15.0  # m/s: faster than any body part in the clips (a kick's foot reaches ~8)


def runaway_problem(metrics: dict) -> str | None:
    """What is wrong with a rollout whose garment blew up or flew off (NaN, or a vertex
    faster than ``RUNAWAY_SPEED``), from ``sequence_metrics``' result; None when it is sound."""
    if not metrics["finite"]:
        return "the garment's positions hold NaN or inf"
    if not metrics["max_speed"] < RUNAWAY_SPEED:
        return (f"a garment vertex reached {metrics['max_speed']:.1f} m/s (over {RUNAWAY_SPEED:g}: the garment ran "
                f"away or fell off the body)")
    return None


def body_signed_distances(garment_vertices: torch.Tensor, body_vertices: torch.Tensor, body_faces: torch.Tensor,
                          proximity: BodyProximity | None = None) -> torch.Tensor:
    """(T,V,3), (T,Vb,3), (Fb,3) -> (T,V) signed distance of each garment vertex to the posed body
    (inf beyond 0.5 m); ``proximity``: a search over ``body_faces`` to reuse."""
    return signed_distances_along(proximity or BodyProximity(body_faces), garment_vertices, body_vertices)


def vertex_speeds(garment_vertices: torch.Tensor, dt: float) -> torch.Tensor:
    """(T,V,3) -> (T−1,V) speed of every vertex between consecutive frames, m/s."""
    return (garment_vertices[1:] - garment_vertices[:-1]).norm(dim=-1) / dt


def kinetic_energy(garment_vertices: torch.Tensor, masses: torch.Tensor, dt: float) -> torch.Tensor:
    """(T,V,3), (V,) kg -> (T−1,) Σ ½ m v² per frame step, joules."""
    velocities = (garment_vertices[1:] - garment_vertices[:-1]) / dt
    return 0.5 * (masses.to(velocities) * velocities.square().sum(-1)).sum(-1)


def sequence_metrics(garment_vertices: torch.Tensor, rest: ClothRest, body_vertices: torch.Tensor,
                     body_faces: torch.Tensor, origin: torch.Tensor, dt: float,
                     drape: tuple[torch.Tensor, torch.Tensor] | None = None,
                     hem: torch.Tensor | None = None) -> dict[str, float]:
    """Every metric of REFERENCE.md for one sequence.

    Args:
        garment_vertices: (T,V,3); rest: the garment's rest (canonical template) state.
        body_vertices: (T,Vb,3) posed body; body_faces: (Fb,3).
        origin: (3,) the body root at frame 0: gravity energy is measured from it.
        dt: seconds per frame.
        drape: the garment's drape (V,3) and the canonical body it rests on (Vb,3), where the
            sequence started from; given, ``detached_pct`` is reported.
        hem: (L,) the garment's hem loop in order (``geometry.boundary.lowest_loop``); given,
            ``hem_area_cm2`` is reported.

    Returns:
        edge_error_pct, area_error_pct (GAPS), collision_pct (d < 0), collision_1mm_pct
        (HOOD: d < 1 mm), and the mean per-frame strain, bending, inertia, gravity (J,
        HOOD protocol, frames t >= 2); ``finite`` (no NaN/inf) and ``max_speed`` (m/s, the
        fastest vertex over the sequence); ``detached_pct`` (% of vertex-frames more than
        ``DETACH_MARGIN`` farther from the skin than in the drape) when ``drape`` is given;
        ``hem_area_cm2`` (the mean over frames of the area the hem loop encloses seen from above)
        when ``hem`` is given.
    """
    x = garment_vertices.double()
    proximity = BodyProximity(body_faces)
    distances = body_signed_distances(garment_vertices, body_vertices, body_faces, proximity)
    metrics = {
        "edge_error_pct": float(edge_error_pct(x, rest)),
        "area_error_pct": float(area_error_pct(x, rest)),
        "collision_pct": float(collision_pct(distances, 0.0)),
        "collision_1mm_pct": float(collision_pct(distances, HOOD_COLLISION_THRESHOLD)),
        "finite": bool(torch.isfinite(x).all()),
        "max_speed": float(vertex_speeds(x, dt).max()) if x.shape[0] > 1 else 0.0,
    }
    if drape is not None:
        drape_vertices, canonical_body = drape
        reference = body_signed_distances(drape_vertices[None], canonical_body[None], body_faces, proximity)[0]
        metrics["detached_pct"] = detached_pct(distances, reference)
    if hem is not None:
        metrics["hem_area_cm2"] = float(enclosed_area(x[:, hem]).mean()) * 1e4
    if x.shape[0] >= 3:
        energies = mean_energies(x - origin.double(), rest, dt=dt)
        metrics.update({"strain": float(energies["stretching"]), "bending": float(energies["bending"]),
                        "inertia": float(energies["inertia"]), "gravity": float(energies["gravity"])})
    return metrics
