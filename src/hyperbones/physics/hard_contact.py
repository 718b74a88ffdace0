"""Hard contact for the teacher's steps: cloth that a step left inside the body goes back out
on the side of the skin it came from.

A limb that moves several centimetres in one frame (a running thigh: ~10 cm at 30 fps)
sweeps into cloth in front of it. Pushing such a vertex to its nearest skin point sends it
out of the back of the limb once it is more than half the limb's width deep, and the
cloth it drags along tears. Instead each vertex that was near the skin before the step
keeps the skin patch it was near: the face it was nearest to, at the face's new place,
bounds it as a half-space, and the strain limiter enforces those half-spaces inside its
sweeps, so the limit's pull and the contact push settle together rather than undoing each
other (``StrainLimiter.project``).

The limiter's pull itself draws cloth into the body where it wraps a limb: a stretched
loop around a thigh shrinks into it. Such cloth was not near the skin before the step, so
no tracked plane holds it, and a nearest-point push afterwards stretches the loop again.
So after the limiter, cloth it left inside gets a plane of its own (its nearest face, at
the margin) and the limiter runs again from there, for up to ``CONTACT_ROUNDS`` rounds;
the slack then comes from the free cloth, as it would in a real garment (the round count:
docs/experiments/*-teacher-contact-rounds.md). A last nearest-point push catches
what no plane covered.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from hyperbones.geometry.surface import Nearest, carried_points, found_points, push_outside, search_ranges
from hyperbones.physics.contact_planes import ContactPlanes
from hyperbones.physics.strain_limit import StrainLimiter

if TYPE_CHECKING:  # Warp's search or its torch twin (``geometry.torch_proximity``): the same API
    from hyperbones.geometry.proximity import BodyProximity

# Limiter passes at most after the first, each with planes for the cloth the last one left inside.
CONTACT_ROUNDS = 8
QUERY_DISTANCE = 0.1  # m: the teacher's steps look for nearest body faces this far out


def constrain_step(positions: torch.Tensor, velocities: torch.Tensor, limiter: StrainLimiter, proximity: BodyProximity,
                   nearest_before: Nearest, body_after: torch.Tensor, movable: torch.Tensor, margin: float,
                   query_distance: float, rounds: int = CONTACT_ROUNDS,
                   vertex_garment: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Strain limiting and hard contact after a step; every move is kept as velocity.

    positions, velocities: (V,3) the step's raw result (per-step displacement);
    limiter: the garment's strain limiting; proximity: the body's BVH (moved to ``body_after`` (Vb,3)
    here, where it stays for the next step); nearest_before: ``proximity.query`` of the
    positions before the step on the body before it; movable: (V,) bool (not pinned);
    rounds: limiter passes after the first, each adding planes for cloth left inside;
    vertex_garment: (V,) int64 the garment of each vertex when the positions are several
    garments in one (``training.episode_batch``): each garment then stops its rounds where
    it would alone, rather than take more limiter passes while another still has cloth inside.
    Returns positions, velocities, both (V,3).
    """
    proximity.update(body_after)
    # Every search below is bounded by a skin point known on ``body_after`` (the last answer's,
    # or the one before the step carried onto the body now): the same answers, less searching.
    carried = carried_points(nearest_before, body_after, proximity.faces)
    reached = proximity.query(positions, max_distance=search_ranges(positions, carried, query_distance))
    inside = movable & reached.found & (reached.signed_distance < margin)
    planes = ContactPlanes.tracked(nearest_before, body_after, proximity.faces, inside, margin)
    limited = limiter.project(positions, planes)
    after = proximity.query(limited, max_distance=search_ranges(limited, found_points(reached), query_distance))
    held = torch.zeros_like(movable)
    held[planes.vertex] = True
    for _ in range(rounds):
        left_inside = movable & ~held & (after.signed_distance < 0)  # < 0: a face was found
        if not bool(left_inside.any()):
            break
        planes = planes + ContactPlanes.nearest(after, left_inside, margin)
        held |= left_inside
        projected = limiter.project(limited, planes)
        if vertex_garment is not None:  # garments are not linked: a garment that left none inside keeps its place
            projected = torch.where(_anywhere_in_garment(left_inside, vertex_garment)[:, None], projected, limited)
        limited = projected
        after = proximity.query(limited, max_distance=search_ranges(limited, found_points(after), query_distance))
    final = push_outside(limited, after, margin, movable=movable & (after.signed_distance < 0))
    return final, velocities + (final - positions)


def _anywhere_in_garment(mask: torch.Tensor, vertex_garment: torch.Tensor) -> torch.Tensor:
    """(V,) bool, (V,) garment ids -> (V,) bool: ``mask`` holds somewhere in the vertex's garment."""
    hit = torch.zeros_like(mask)  # one slot per garment id (ids < V: every garment has a vertex)
    hit[vertex_garment[mask]] = True
    return hit[vertex_garment]


__all__ = ["constrain_step", "CONTACT_ROUNDS", "QUERY_DISTANCE"]
