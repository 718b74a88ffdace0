"""Body contact for the per-frame runtime: garment vertices inside the body pushed out,
then the garment's edges pulled back towards their rest lengths.

Module A has no state to resolve contact with (its L_interp only discourages penetration),
so after each frame the vertices that end up inside the body, or closer to it than the margin,
are moved to the margin outside their nearest body face, along its normal (the projection the
teacher's hard contact starts from); a vertex that lands inside a neighbouring face (in a
crease) is projected again. Then, with an ``EdgeProjection`` per character, rounds of edge
projection (skin-near vertices held outside their face's plane) and push-out follow, each
from the last round's nearest faces; before them, untangling brings back vertices the push-out
sent out on a limb's far side from their neighbours. Every setting: ``RuntimeConfig``;
measurements: ``docs/experiments/*runtime*.md``.
"""

from __future__ import annotations

import torch

from hyperbones.errors import ParameterError
from hyperbones.runtime.config import RuntimeConfig


class BodyContact:
    """One BVH per character over its body's triangles (F,3), refit every frame."""

    def __init__(self, body_faces: torch.Tensor, characters: int, device: str | torch.device = "cpu",
                 projections: list | None = None, config: RuntimeConfig = RuntimeConfig()):
        """projections: one ``EdgeProjection`` per character, or None; config: the margin, query
        distances, rounds, plane reach and untangling (``config.untangle``: after the first
        push-out, bring back the vertices pushed out on the far side of a limb from their
        neighbours; with projections only, whose edges say who the neighbours are)."""
        from hyperbones.geometry.proximity import BodyProximity  # Warp: only when contact is asked for

        if projections is not None and len(projections) != characters:
            raise ParameterError(f"contact got {len(projections)} edge projections for {characters} characters")
        self.config = config
        self.margin = config.contact_margin
        self.proximities = [BodyProximity(body_faces, device=device) for _ in range(characters)]
        self.projections = projections or [None] * characters
        # Per character with a projection: its garment's (E,2) edges and (V,) vertex degrees on the device.
        self.neighbours = [None if projection is None or not config.untangle else
                           (projection.edges.to(device), torch.bincount(
                               projection.edges.reshape(-1), minlength=projection.difference.shape[1]).to(device))
                           for projection in self.projections]
        # Per character, the last call's last query (``Nearest`` of each garment vertex; its
        # points lie on that call's body).
        self.last_nearest: list = [None] * characters

    def forget(self) -> None:
        """Drop what the last call found (a new motion starts)."""
        self.last_nearest = [None] * len(self.proximities)

    def skin_motion(self, character: int, body: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
        """How the skin under ``character``'s garment moved from the last call's body to ``body``
        (Vb,3): (V,3) the displacement of each vertex's nearest skin point at the last call (0
        where none was found) and (V,) that call's signed distances (+inf where none was found);
        None before a first call."""
        nearest = self.last_nearest[character]
        if nearest is None:
            return None
        from hyperbones.geometry.proximity import surface_points

        now = surface_points(body, self.proximities[character].faces, nearest.face, nearest.barycentric)
        return (now - nearest.point) * nearest.found[:, None], nearest.signed_distance

    def __call__(self, garments: list[torch.Tensor], bodies: torch.Tensor) -> list[torch.Tensor]:
        """N garments (V_i,3) and the N posed bodies (N,Vb,3) at the same frame -> the garments
        pushed out (and, with projections, ``contact_rounds`` times projected and pushed out)."""
        from hyperbones.physics.contact_planes import ContactPlanes

        config = self.config
        if bodies.shape[0] != len(self.proximities):
            raise ParameterError(f"contact needs one posed body per character ({len(self.proximities)}), "
                                 f"got {bodies.shape[0]}")
        out = []
        for index, (proximity, projection, neighbours, garment, body) in enumerate(
                zip(self.proximities, self.projections, self.neighbours, garments, bodies)):
            proximity.update(body)
            garment, nearest = self._push_out(proximity, garment)
            if neighbours is not None:
                garment, nearest = self._untangle(proximity, *neighbours, garment, nearest)
            for _ in range(config.contact_rounds if projection is not None else 0):
                planes = ContactPlanes.nearest(nearest, nearest.signed_distance < config.plane_reach, self.margin)
                garment = projection.project(garment, planes)
                # The projection moves vertices away from the skin planes too; what it moved
                # inside comes out again.
                garment, nearest = self._push_out(proximity, garment, config.round_query_distance)
            self.last_nearest[index] = nearest
            out.append(garment)
        return out

    def _untangle(self, proximity, edges: torch.Tensor, degree: torch.Tensor, garment: torch.Tensor, nearest):
        """Vertices near the skin whose face normal points against the sum of their neighbours'
        (a limb that went through the cloth: the nearest-face push-out sent these out on its far
        side, their neighbours on the near one, stretching the edges between round the limb)
        moved to their neighbours' mean and pushed out again. edges: (E,2); degree: (V,)."""
        first, second = edges[:, 0], edges[:, 1]
        near = (nearest.found & (nearest.signed_distance < self.config.plane_reach))[:, None].to(garment.dtype)
        normal = nearest.normal * near
        around = torch.zeros_like(garment).index_add_(0, first, normal[second]).index_add_(0, second, normal[first])
        against = (normal * around).sum(1) < -self.config.untangle_cosine * around.norm(dim=1)
        index = against.nonzero().squeeze(1)
        if not len(index):
            return garment, nearest
        total = torch.zeros_like(garment).index_add_(0, first, garment[second]).index_add_(0, second, garment[first])
        garment = garment.index_copy(0, index, total[index] / degree[index, None].clamp_min(1).to(garment.dtype))
        return self._push_out(proximity, garment)

    def _push_out(self, proximity, garment: torch.Tensor, query_distance: float | None = None):
        """(V,3) -> (V,3) with every vertex inside the body or within the margin moved out to
        the margin (up to ``push_rounds`` projections), and the first query's ``Nearest`` (faces
        looked for within ``query_distance``, default ``config.query_distance``)."""
        from hyperbones.geometry.proximity import push_outside

        query_distance = self.config.query_distance if query_distance is None else query_distance
        nearest = proximity.query(garment, max_distance=query_distance)
        moved = nearest.found & (nearest.signed_distance < self.margin)
        garment = push_outside(garment, nearest, self.margin)
        for _ in range(self.config.push_rounds - 1):
            # Pushed off one face, a vertex in a crease can land inside the next one.
            index = torch.nonzero(moved).squeeze(1)
            if len(index) == 0:
                break
            again = proximity.query(garment[index], max_distance=self.config.query_distance)
            inside = again.found & (again.signed_distance < 0)
            if not bool(inside.any()):
                break
            garment = garment.index_copy(0, index[inside], push_outside(garment[index], again, self.margin)[inside])
            moved = torch.zeros_like(moved).index_fill_(0, index[inside], True)
        return garment, nearest
