"""Body contact for the per-frame runtime: garment vertices inside the body pushed out,
then the garment's edges pulled back towards their rest lengths.

Module A has no state to resolve contact with (its L_interp only discourages penetration),
so after each frame the vertices that end up inside the body, or closer to it than the margin,
are moved to the margin outside their nearest body face, along its normal (the projection the
teacher's hard contact starts from); a vertex that lands inside a neighbouring face (in a
crease) is moved out of both faces, and one caught between two body parts closer than twice
the margin is left halfway between them (``geometry.surface.push_outside_two``). Then, with
an ``EdgeProjection`` per character, rounds of edge projection (skin-near vertices held
outside their face's plane) and push-out follow, each from the last round's nearest faces;
before them, untangling brings back vertices the push-out sent out on a limb's far side
from their neighbours. Every setting: ``RuntimeConfig``;
measurements: ``docs/experiments/*runtime*.md``.
"""

from __future__ import annotations

import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.search import search_backend
from hyperbones.geometry.sparse import to_csr
from hyperbones.geometry.surface import (carried_points, found_points, push_outside, push_outside_two,
                                        search_ranges)
from hyperbones.runtime.config import RuntimeConfig
from hyperbones.runtime.stage_clock import NO_CLOCK

STUCK_STEP = 1e-5  # m: a push-out round that moves a vertex less than this has stopped helping it


class BodyContact:
    """One nearest-face search per character over its body's triangles (F,3), moved to the
    body every frame: Warp's BVH, or the same search in torch (``geometry.torch_proximity``,
    where Warp is missing or the characters live on a GPU). Both give the exact nearest face."""

    def __init__(self, body_faces: torch.Tensor, characters: int, device: str | torch.device = "cpu",
                 projections: list | None = None, config: RuntimeConfig = RuntimeConfig(), search: str = "auto"):
        """projections: one ``EdgeProjection`` per character, or None; config: the margin, query
        distances, rounds, plane reach and untangling (``config.untangle``: after the first
        push-out, bring back the vertices pushed out on the far side of a limb from their
        neighbours; with projections only, whose edges say who the neighbours are);
        search: "warp", "torch" or "auto" (``search_backend``)."""
        if projections is not None and len(projections) != characters:
            raise ParameterError(f"contact got {len(projections)} edge projections for {characters} characters")
        self.config = config
        self.margin = config.contact_margin
        self.search = search_backend(search, device)
        if self.search == "warp":
            from hyperbones.geometry.proximity import BodyProximity as Search
        else:
            from hyperbones.geometry.torch_proximity import TorchProximity as Search
        self.proximities = [Search(body_faces, device=device) for _ in range(characters)]
        self.projections = projections or [None] * characters
        # Per character with a projection: its garment's (V,V) sparse adjacency and (V,) vertex degrees on the device.
        self.neighbours = [None if projection is None or not config.untangle else
                           _adjacency(projection.edges, projection.difference.shape[1], device)
                           for projection in self.projections]
        # Per character, the last call's last query (``Nearest`` of each garment vertex; its
        # points lie on that call's body).
        self.last_nearest: list = [None] * characters
        # Per character, those skin points where the current frame's body has them (V,3; NaN
        # where none was found), made once a frame by ``skin_now`` for the follow and the search.
        self._skin_now: list = [None] * characters
        self.clock = NO_CLOCK  # ``Simulator.profile`` sets a StageClock
        self.fused = True  # push-outs in one launch where the search has one (Warp's); False: the torch rounds

    def forget(self) -> None:
        """Drop what the last call found (a new motion starts)."""
        self.last_nearest = [None] * len(self.proximities)
        self._skin_now = [None] * len(self.proximities)

    def skin_motion(self, character: int, body: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
        """How the skin under ``character``'s garment moved from the last call's body to ``body``
        (Vb,3): (V,3) the displacement of each vertex's nearest skin point at the last call (0
        where none was found) and (V,) that call's signed distances (+inf where none was found);
        None before a first call."""
        nearest = self.last_nearest[character]
        if nearest is None:
            return None
        now = self.skin_now(character, body)
        return torch.nan_to_num(now - nearest.point, nan=0.0), nearest.signed_distance

    def skin_now(self, character: int, body: torch.Tensor) -> torch.Tensor | None:
        """(V,3) where the skin points of ``character``'s last call lie on ``body`` (Vb,3), this
        frame's posed body (NaN where that call found none; None before a first call). Made
        once a frame: the follow and this frame's first search both use them."""
        nearest = self.last_nearest[character]
        if nearest is None:
            return None
        if self._skin_now[character] is None:
            self._skin_now[character] = carried_points(nearest, body, self.proximities[character].faces)
        return self._skin_now[character]

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
            clock = self.clock
            with clock.stage("contact queries"):
                proximity.update(body)
                # Last frame's skin points, where the body is now: each bounds its vertex's search.
                skin = self.skin_now(index, body)
                queried_at = garment  # (V,3) where each row of ``nearest`` was searched from
                garment, nearest = self._push_out(proximity, garment, config.query_distance, skin)
            if neighbours is not None:
                with clock.stage("untangling"):
                    garment, nearest, queried_at = self._untangle(proximity, *neighbours, garment, nearest,
                                                                  queried_at)
            # Every search so far looked ``query_distance`` far.
            floor = _distance_floor(nearest, config.query_distance)
            for _ in range(config.contact_rounds if projection is not None else 0):
                with clock.stage("projection"):
                    planes = ContactPlanes.nearest(nearest, nearest.signed_distance < config.plane_reach, self.margin)
                    garment = projection.project(garment, planes)
                # The projection moves vertices away from the skin planes too; what it moved
                # inside comes out again.
                with clock.stage("contact queries"):
                    garment, nearest, queried_at, floor = self._search_again(proximity, garment, nearest,
                                                                             queried_at, floor)
            self.last_nearest[index], self._skin_now[index] = nearest, None
            out.append(garment)
        return out

    def push_out_rows(self, character: int, garment: torch.Tensor, rows: torch.Tensor,
                      skin: torch.Tensor | None = None) -> torch.Tensor:
        """(V,3) ``character``'s garment with its vertices ``rows`` (M,) pushed out of this
        frame's body (call after this frame's ``__call__``, which moved the body); skin: (M,3)
        a skin point of each, bounding its search (NaN: none). Nothing is recorded: the next
        frame reads the records of the vertices the contact corrected (a proxy's)."""
        if not len(rows):
            return garment
        pushed, _ = self._push_out(self.proximities[character], garment[rows], self.config.query_distance, skin)
        return garment.index_copy(0, rows, pushed)

    def _untangle(self, proximity, adjacency: torch.Tensor, degree: torch.Tensor, garment: torch.Tensor, nearest,
                  queried_at: torch.Tensor):
        """Vertices near the skin whose face normal points against the sum of their neighbours'
        (a limb that went through the cloth: the nearest-face push-out sent these out on its far
        side, their neighbours on the near one, stretching the edges between round the limb)
        moved to their neighbours' mean and pushed out again. adjacency: (V,V) sparse CSR, 1 per
        edge both ways (a sum over neighbours is one product); degree: (V,); ``nearest`` was
        queried at ``queried_at`` (V,3), before the push-out that led to ``garment``.

        Only the vertices that moved since that query are searched again: the others would find
        what they found then (same point, same body), so the answer is that of a full search."""
        near = (nearest.found & (nearest.signed_distance < self.config.plane_reach))[:, None].to(garment.dtype)
        normal = nearest.normal * near
        around = adjacency @ normal
        against = (normal * around).sum(1) < -self.config.untangle_cosine * around.norm(dim=1)
        index = against.nonzero().squeeze(1)
        if not len(index):
            return garment, nearest, queried_at
        total = adjacency @ garment
        garment = garment.index_copy(0, index, total[index] / degree[index, None].clamp_min(1).to(garment.dtype))
        moved = (garment != queried_at).any(1).nonzero().squeeze(1)
        pushed, found = self._push_out(proximity, garment[moved], self.config.query_distance,
                                       found_points(nearest)[moved])
        return (garment.index_copy(0, moved, pushed), nearest.with_rows(moved, found),
                queried_at.index_copy(0, moved, garment[moved]))

    def _search_again(self, proximity, garment: torch.Tensor, nearest, queried_at: torch.Tensor,
                      floor: torch.Tensor):
        """The push-out after a projection round, searching only where the answer can have
        changed: (V,3) garment, the ``Nearest`` of each vertex, (V,3) where each was measured
        from and (V,) how far from the skin it certainly was there (``floor``) -> the same four
        after the push-out.

        A vertex at least f from the skin that moved by s since is at least f − s away now.
        Where that exceeds this search's range (``config.round_query_distance``) the search
        would find nothing that matters: the vertex keeps its record, which beyond the range no
        later step reads (the follow and the planes look nearer), so the output is that of
        searching every vertex. A vertex found outside that is still more than
        ``config.round_search_gap`` away keeps its record too (below the range, an
        approximation: its face may no longer be the nearest; it cannot be within the margin).
        """
        config = self.config
        shift = (garment - queried_at).norm(dim=1)
        clear = floor - shift  # negative: maybe inside, searched however far from the surface
        # A vertex found outside and clear by the gap keeps its record (0: no gap, the exact search).
        gap = min(config.round_search_gap or config.round_query_distance, config.round_query_distance)
        reach = torch.where(nearest.found & (floor > 0), gap, config.round_query_distance)
        search = (clear <= reach).nonzero().squeeze(1)
        pushed, found = self._push_out(proximity, garment[search], config.round_query_distance,
                                       found_points(nearest)[search])
        found_floor = _distance_floor(found, config.round_query_distance)
        # The rest keep their record as it was measured from ``queried_at``, which is what
        # bounds their distance in the next round.
        return (garment.index_copy(0, search, pushed), nearest.with_rows(search, found),
                queried_at.index_copy(0, search, garment[search]),
                floor.index_copy(0, search, found_floor))

    def _push_out(self, proximity, garment: torch.Tensor, query_distance: float, skin: torch.Tensor | None = None):
        """(V,3) -> (V,3) with every vertex inside the body or within the margin moved out to
        the margin (up to ``push_rounds`` projections), and the first query's ``Nearest`` (faces
        looked for within ``query_distance``).

        skin: (V,3) a point on the body's surface as it is now for each vertex (NaN where none
        is known), e.g. where the last query found its nearest face. The distance to it bounds
        the vertex's distance to the body, so the search looks no farther: same answer, less work.

        Warp's search does all of it in one launch (``BodyProximity.push_out``, the same pushes
        one vertex a thread); the torch search runs the rounds below over all vertices at once.
        """
        if self.fused and hasattr(proximity, "push_out"):
            return proximity.push_out(garment, skin, query_distance, self.config.query_distance, self.margin,
                                      self.config.push_rounds, STUCK_STEP)
        nearest = proximity.query(garment, max_distance=search_ranges(garment, skin, query_distance))
        moved = nearest.found & (nearest.signed_distance < self.margin)
        garment = push_outside(garment, nearest, self.margin)
        index = torch.nonzero(moved).squeeze(1)
        last_normal, last_target = nearest.normal[index], garment[index]
        for _ in range(self.config.push_rounds - 1):
            # Pushed off one face, a vertex in a crease can land inside the next one.
            if len(index) == 0:
                break
            # Any skin point bounds a search; the one each vertex was first pushed from is close by.
            again = proximity.query(garment[index], max_distance=search_ranges(
                garment[index], nearest.point[index], self.config.query_distance))
            inside = again.found & (again.signed_distance < 0)
            if not bool(inside.any()):
                break
            pushed, trapped = push_outside_two(garment[index], again, self.margin, last_normal, last_target)
            # A vertex trapped between two body parts, or one its push no longer moves (outside its
            # nearest face yet inside the body, where two parts overlap), is where no push can do
            # better: it stops.
            stuck = trapped | ((pushed - garment[index]).norm(dim=1) < STUCK_STEP)
            garment = garment.index_copy(0, index[inside], pushed[inside])
            keep = inside & ~stuck
            index, last_normal, last_target = index[keep], again.normal[keep], pushed[keep]
        return garment, nearest


def _adjacency(edges: torch.Tensor, vertices: int, device: str | torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """(E,2) undirected edges of a garment of ``vertices`` -> its (V,V) float32 sparse CSR
    adjacency on ``device`` and (V,) vertex degrees: a neighbour sum as one sparse product,
    ~10x faster on a CPU than two ``index_add_`` over the edges (0.04 against 0.36 ms at 5k,
    docs/experiments/*-realtime-runtime-3.md)."""
    first, second = edges[:, 0], edges[:, 1]
    pairs = torch.stack([torch.cat([first, second]), torch.cat([second, first])])
    adjacency = to_csr(torch.sparse_coo_tensor(pairs, torch.ones(pairs.shape[1]), (vertices, vertices),
                                               check_invariants=True))
    return adjacency.to(device), torch.bincount(edges.reshape(-1), minlength=vertices).to(device)


def _distance_floor(nearest, searched: float) -> torch.Tensor:
    """(V,) how far each point of a query that looked ``searched`` far certainly is from the
    skin: its signed distance (negative inside), or ``searched`` where it found no face."""
    return torch.where(nearest.found, nearest.signed_distance, torch.full_like(nearest.signed_distance, searched))
