"""Body contact for the per-frame runtime: garment vertices inside the body pushed out,
then the garment's edges pulled back towards their rest lengths.

Module A has no state to resolve contact with (its L_interp only discourages penetration),
so after each frame the vertices that end up inside the body, or closer to it than
``margin``, are moved to ``margin`` outside their nearest body face, along its normal (the
projection the teacher's hard contact starts from, without its strain limiting); a vertex
that lands inside a neighbouring face (in a crease) is projected again, up to ``ROUNDS``.
Cost per frame: one BVH refit over the posed body, one nearest-face query per garment
vertex within ``QUERY_DISTANCE`` and the re-queries; on the 8k-vertex dress ~18 ms on one
CPU core (``bench``: hyperbones against hyperbones-raw), of which the first query is ~9 ms.

Edge projection (``projections``, ``runtime.isometry.EdgeProjection``): after the push-out,
the garment's edges are pulled back towards the teacher's band around their rest lengths,
with the vertices found within ``PLANE_REACH`` of the skin held outside their face's plane
after every iteration; what the projection moved inside is then pushed out again. The two
push-outs and 10 projection iterations cost ~45 ms per frame on the 8k dress (one CPU core).
"""

from __future__ import annotations

import torch

from hyperbones.errors import ParameterError
from hyperbones.physics.energies import COLLISION_EPSILON

QUERY_DISTANCE = 0.1  # m: body faces are looked for this far from each garment vertex
ROUNDS = 4  # projections at most; later ones only for vertices a projection left inside
PLANE_REACH = 0.01  # m: vertices this close to the skin keep to its outside while edges are limited


class BodyContact:
    """One BVH per character over its body's triangles (F,3), refit every frame."""

    def __init__(self, body_faces: torch.Tensor, characters: int, device: str | torch.device = "cpu",
                 margin: float = COLLISION_EPSILON, projections: list | None = None):
        """projections: one ``EdgeProjection`` per character, or None."""
        from hyperbones.geometry.proximity import BodyProximity  # Warp: only when contact is asked for

        if projections is not None and len(projections) != characters:
            raise ParameterError(f"contact got {len(projections)} edge projections for {characters} characters")
        self.margin = margin
        self.proximities = [BodyProximity(body_faces, device=device) for _ in range(characters)]
        self.projections = projections or [None] * characters

    def __call__(self, garments: list[torch.Tensor], bodies: torch.Tensor) -> list[torch.Tensor]:
        """N garments (V_i,3) and the N posed bodies (N,Vb,3) at the same frame -> the garments
        pushed out (and, with projections, their edges projected, then pushed out again)."""
        from hyperbones.physics.contact import ContactPlanes

        if bodies.shape[0] != len(self.proximities):
            raise ParameterError(f"contact needs one posed body per character ({len(self.proximities)}), "
                                 f"got {bodies.shape[0]}")
        out = []
        for proximity, projection, garment, body in zip(self.proximities, self.projections, garments, bodies):
            proximity.update(body)
            garment, nearest = self._push_out(proximity, garment)
            if projection is not None:
                planes = ContactPlanes.nearest(nearest, nearest.signed_distance < PLANE_REACH, self.margin)
                garment = projection.project(garment, planes)
                # The projection moves vertices away from the skin planes too; what it moved
                # inside comes out again.
                garment, _ = self._push_out(proximity, garment)
            out.append(garment)
        return out

    def _push_out(self, proximity, garment: torch.Tensor):
        """(V,3) -> (V,3) with every vertex inside the body or within the margin moved out to
        the margin (up to ``ROUNDS`` projections), and the first query's ``Nearest``."""
        from hyperbones.geometry.proximity import push_outside

        nearest = proximity.query(garment, max_distance=QUERY_DISTANCE)
        moved = nearest.found & (nearest.signed_distance < self.margin)
        garment = push_outside(garment, nearest, self.margin)
        for _ in range(ROUNDS - 1):
            # Pushed off one face, a vertex in a crease can land inside the next one.
            index = torch.nonzero(moved).squeeze(1)
            if len(index) == 0:
                break
            again = proximity.query(garment[index], max_distance=QUERY_DISTANCE)
            inside = again.found & (again.signed_distance < 0)
            if not bool(inside.any()):
                break
            garment = garment.index_copy(0, index[inside], push_outside(garment[index], again, self.margin)[inside])
            moved = torch.zeros_like(moved).index_fill_(0, index[inside], True)
        return garment, nearest
