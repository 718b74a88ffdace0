"""Body contact for the per-frame runtime: garment vertices inside the body pushed out,
then the garment's edges pulled back towards their rest lengths.

Module A has no state to resolve contact with (its L_interp only discourages penetration),
so after each frame the vertices that end up inside the body, or closer to it than
``margin``, are moved to ``margin`` outside their nearest body face, along its normal (the
projection the teacher's hard contact starts from, without its strain limiting); a vertex
that lands inside a neighbouring face (in a crease) is projected again, up to ``ROUNDS``.
Cost of one push-out: one nearest-face query per garment vertex within ``QUERY_DISTANCE``
and the re-queries (plus one BVH refit over the posed body per frame).

Edge projection (``projections``, ``runtime.isometry.EdgeProjection``): after the push-out,
``PROJECTION_ROUNDS`` rounds each pull the garment's edges towards their rest lengths, with
the vertices found within ``PLANE_REACH`` of the skin held outside their face's plane after
every iteration, then push out what the projection moved inside, re-finding the nearest
faces for the next round. Rounds and reach were chosen on the held-out clip 143_06
(1500-vertex dress / tshirt, default body, step-13000 model, projection anchor α = 0.005 then;
ε_e %):

| follow | rounds × iterations | reach | ε_e dress / tshirt | queries per frame |
|---|---|---|---|---|
| off | 1 × 10 | 1 cm | 3.50 / 4.30 | 2 |
| off | 2 × 5 | 1 cm | 3.07 / 3.45 | 3 |
| off | 3 × 4 | 3 cm | 2.85 / 3.25 | 4 |
| 0.6, heading frame only | 3 × 4 | 3 cm | 2.44 / 3.06 | 4 |
| 0.6, heading frame only | 2 × 5 | 3 cm | 2.54 / 3.15 | 3 |
| 0.6, with the skin carry | 2 × 5 | 3 cm | 2.55 / 3.08 | 3 (chosen: one query less) |

Untangling (``untangle``, on by default with projections): where a limb went through loose
cloth, the nearest-face push-out sends some vertices out on the limb's far side and their
neighbours on the near one, and the edges between wrap round it. After the first push-out,
a vertex within ``PLANE_REACH`` of the skin whose face normal points against the sum of its
neighbours' (cosine below −``UNTANGLE_COSINE``) moves to its neighbours' mean and is pushed
out again (one more query, over every vertex, on the frames that have any). Chosen on
training clips 16_07 and 02_03 (first 150 frames) × two held-out bodies, 1500 vertices,
step-13000 model; without → with it, ratios of the means to the teacher's ε_a and LBS's
inertia, and the strain energy (J):

| | tshirt | tshirt-open | pants | long-skirt | dress |
|---|---|---|---|---|---|
| ε_a ÷ teacher's | 1.04 → 1.01 | 1.31 → 1.31 | 1.04 → 1.03 | 0.72 → 0.71 | 1.08 → 1.06 |
| inertia ÷ LBS's | 0.93 → 0.93 | 1.00 → 1.01 | 0.81 → 0.81 | 0.78 → 0.78 | 0.82 → 0.83 |
| strain (J) | 0.27 → 0.13 | 0.82 → 0.78 | 0.27 → 0.28 | 0.85 → 0.72 | 0.33 → 0.31 |

Ending on a projection instead of a push-out changed ε_e by < 0.05 and left 0.3 % of the
vertices inside (against 0.1 %). Cost on the 8k dress, one CPU core: the first query ~8 ms,
each later one ~5 ms (``ROUND_QUERY_DISTANCE``), each projection iteration ~1.5 ms.
"""

from __future__ import annotations

import torch

from hyperbones.errors import ParameterError
from hyperbones.physics.energies import COLLISION_EPSILON

QUERY_DISTANCE = 0.1  # m: body faces are looked for this far from each garment vertex
ROUND_QUERY_DISTANCE = 0.04  # m: and after a projection round (which moves vertices by millimetres;
# the nearer bound lets the BVH skip the far cloth: 4.7 against 7.7 ms on the 8k dress)
ROUNDS = 4  # projections at most; later ones only for vertices a projection left inside
PLANE_REACH = 0.03  # m: vertices this close to the skin keep to its outside while edges are projected
PROJECTION_ROUNDS = 2  # projection and push-out, each round from the last round's nearest faces
UNTANGLE_COSINE = 0.3  # a vertex whose skin normal points against its neighbours' (below −this) is on the
# far side of a limb from them


class BodyContact:
    """One BVH per character over its body's triangles (F,3), refit every frame."""

    def __init__(self, body_faces: torch.Tensor, characters: int, device: str | torch.device = "cpu",
                 margin: float = COLLISION_EPSILON, projections: list | None = None, untangle: bool = True):
        """projections: one ``EdgeProjection`` per character, or None; untangle: after the first
        push-out, bring back the vertices pushed out on the far side of a limb from their
        neighbours (``_untangle``; with projections only, whose edges say who the neighbours are)."""
        from hyperbones.geometry.proximity import BodyProximity  # Warp: only when contact is asked for

        if projections is not None and len(projections) != characters:
            raise ParameterError(f"contact got {len(projections)} edge projections for {characters} characters")
        self.margin = margin
        self.proximities = [BodyProximity(body_faces, device=device) for _ in range(characters)]
        self.projections = projections or [None] * characters
        # Per character with a projection: its garment's (E,2) edges and (V,) vertex degrees on the device.
        self.neighbours = [None if projection is None or not untangle else
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
        pushed out (and, with projections, ``PROJECTION_ROUNDS`` times projected and pushed out)."""
        from hyperbones.physics.contact import ContactPlanes

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
            for _ in range(PROJECTION_ROUNDS if projection is not None else 0):
                planes = ContactPlanes.nearest(nearest, nearest.signed_distance < PLANE_REACH, self.margin)
                garment = projection.project(garment, planes)
                # The projection moves vertices away from the skin planes too; what it moved
                # inside comes out again.
                garment, nearest = self._push_out(proximity, garment, ROUND_QUERY_DISTANCE)
            self.last_nearest[index] = nearest
            out.append(garment)
        return out

    def _untangle(self, proximity, edges: torch.Tensor, degree: torch.Tensor, garment: torch.Tensor, nearest):
        """Vertices near the skin whose face normal points against the sum of their neighbours'
        (a limb that went through the cloth: the nearest-face push-out sent these out on its far
        side, their neighbours on the near one, stretching the edges between round the limb)
        moved to their neighbours' mean and pushed out again. edges: (E,2); degree: (V,)."""
        first, second = edges[:, 0], edges[:, 1]
        near = (nearest.found & (nearest.signed_distance < PLANE_REACH))[:, None].to(garment.dtype)
        normal = nearest.normal * near
        around = torch.zeros_like(garment).index_add_(0, first, normal[second]).index_add_(0, second, normal[first])
        against = (normal * around).sum(1) < -UNTANGLE_COSINE * around.norm(dim=1)
        index = against.nonzero().squeeze(1)
        if not len(index):
            return garment, nearest
        total = torch.zeros_like(garment).index_add_(0, first, garment[second]).index_add_(0, second, garment[first])
        garment = garment.index_copy(0, index, total[index] / degree[index, None].clamp_min(1).to(garment.dtype))
        return self._push_out(proximity, garment)

    def _push_out(self, proximity, garment: torch.Tensor, query_distance: float = QUERY_DISTANCE):
        """(V,3) -> (V,3) with every vertex inside the body or within the margin moved out to
        the margin (up to ``ROUNDS`` projections), and the first query's ``Nearest`` (faces
        looked for within ``query_distance``)."""
        from hyperbones.geometry.proximity import push_outside

        nearest = proximity.query(garment, max_distance=query_distance)
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
