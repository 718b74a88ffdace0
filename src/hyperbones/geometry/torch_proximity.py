"""Nearest body face of points in plain torch: an exact, Warp-free twin of ``BodyProximity``.

Same answer as the Warp BVH (``geometry.proximity``) with its "normal" sign, from torch
alone: it runs where Warp is absent, keeps a query on torch's device and stream, and
answers many points (and batches of bodies) in a few dozen vectorised steps.

How: once per topology the faces are split top-down into clusters of at most S faces and
the clusters into groups of at most G (``build_hierarchy``, from the first body's pose).
Each update fits a sphere to every group, a box (along its mean normal) to every cluster
and the smallest disc in its plane to every face, each holding all it covers. A query then
  1. bounds the distance to every group from below (|p − centre| − radius, one matmul),
  2. takes the exact distance to a few likely faces (nearest discs in the nearest boxes in
     the nearest groups): an upper bound f on the nearest distance,
  3. opens every group, then cluster, then face whose bound is below
     t = min(f, max_distance) + ε and tests those faces exactly: bounds never exceed
     distances, so no face closer than t is skipped and the answer is the true nearest
     face (Warp's up to float32 ties),
  4. signs it by Warp's rule (``_Hierarchy.sign_weights``).
Every step is a handful of tensor operations over flat (point, candidate) lists, chunked
to ``memory_budget``; on the CPU it is several times slower than Warp's BVH.
"""

from __future__ import annotations

import math

import torch

from hyperbones.geometry.surface import Nearest

_SLIVER = 1e-6  # Warp skips faces with |e0 × e1| / (|e0|² + |e1|² + |e2|²) below this
_TIE = 1e-3  # Warp's tie band ε, in mean edge lengths of the body
_SLACK = 1e-5  # metres added to every "bound < t" test, well above float32 rounding of the bounds
_PER_BOUND = 200  # bytes of temporaries per (point, box or disc) bound, for chunking
_PER_RECORD = 500  # bytes of temporaries per (point, face) exact distance


_HIERARCHIES: dict = {}  # (faces' bytes, cluster size, group size, device) -> (slots, real)


CPU_MEMORY_BUDGET = 128 * 2**20
GPU_MEMORY_BUDGET = 2 * 2**30


def default_memory_budget(device: torch.device) -> int:
    """Bytes of temporaries a query chunk may take: 128 MiB on the CPU (chunks that stay
    near the caches); on a GPU up to 2 GiB (an eighth of its free memory at most), since there
    every chunk costs kernel launches and host waits: on an H200, 64 garments of ~2.5k
    points took 307 ms a query in chunks of 128 MiB (about 20 of them)."""
    if device.type != "cuda":
        return CPU_MEMORY_BUDGET
    free, _ = torch.cuda.mem_get_info(device)
    return int(max(CPU_MEMORY_BUDGET, min(GPU_MEMORY_BUDGET, free // 8)))


class TorchProximity:
    """Exact nearest body face of points in plain torch, with the API of ``BodyProximity``.

    Sign: Warp's ``mesh_query_point_sign_normal`` (angle-weighted pseudo-normals), right for
    a closed, outward-wound body such as Anny; there is no winding-number variant.
    Batches: ``update`` also takes (B,Vb,3) bodies; ``query`` then takes (B,...,3) points,
    each row against its own body. ``memory_budget`` (bytes) caps a query's temporaries.
    """

    sign = "normal"

    def __init__(self, faces: torch.Tensor, device: str | torch.device | None = "cpu", cluster_size: int = 12,
                 group_size: int = 8, memory_budget: int | None = None):
        """faces: (F,3) body triangles (counter-clockwise seen from outside); device: where the
        search runs (None: faces'); cluster_size, group_size: S and G of the hierarchy;
        memory_budget: bytes of temporaries per chunk of a query (None: ``default_memory_budget``)."""
        self.device = torch.device(device) if device is not None else faces.device
        self.faces = faces.to(device=self.device, dtype=torch.int64)
        self.cluster_size, self.group_size = int(cluster_size), int(group_size)
        self.memory_budget = int(memory_budget) if memory_budget is not None else default_memory_budget(self.device)
        self._slots: torch.Tensor | None = None  # (H·G·S,) face in each slot of each cluster of each group
        self._real: torch.Tensor | None = None  # (H·G·S,) False where a slot repeats a face as padding
        self._body: _Hierarchy | None = None
        self._batched = False

    def update(self, body_vertices: torch.Tensor) -> None:
        """Move the body to ``body_vertices`` (Vb,3), or a batch (B,Vb,3); the first call also
        builds the hierarchy, from the (first) body's face positions."""
        vertices = body_vertices.detach().to(device=self.device, dtype=torch.float32)
        self._batched = vertices.dim() == 3
        vertices = vertices if self._batched else vertices[None]
        if self._slots is None:
            # Any body of this topology gives a valid hierarchy (the answers are exact either
            # way), so the characters of a crowd share the first one built (0.5 s each).
            key = (self.faces.cpu().numpy().tobytes(), self.cluster_size, self.group_size, str(self.device))
            if key not in _HIERARCHIES:
                slots, real = build_hierarchy(vertices[0][self.faces].cpu(), self.cluster_size, self.group_size)
                _HIERARCHIES[key] = slots.to(self.device), real.to(self.device)
            self._slots, self._real = _HIERARCHIES[key]
        self._body = _Hierarchy(vertices, self.faces, self._slots, self._real, self.cluster_size, self.group_size)

    def query(self, points: torch.Tensor, max_distance: float | torch.Tensor = 1.0) -> Nearest:
        """Nearest body face of each of ``points`` (...,N,3) within ``max_distance`` metres (one
        range, or one per point shaped like ``points`` without its last axis, as ``BodyProximity``).

        Fields come back on ``points``' device, floats in its dtype, shaped like ``points``
        without its last axis. With a batch of B bodies, ``points`` is (B,...,3).
        """
        if self._body is None:
            raise RuntimeError("TorchProximity.query called before update(body_vertices)")
        body = self._body
        if self._batched and (points.dim() < 2 or points.shape[0] != body.batch):
            raise ValueError(f"points {tuple(points.shape)} must be (B,...,3) for a batch of {body.batch} bodies")
        queries = points.detach().to(device=self.device, dtype=torch.float32).reshape(body.batch, -1, 3)
        count = queries.shape[1]
        if isinstance(max_distance, torch.Tensor):
            if max_distance.numel() != body.batch * count:
                raise ValueError(f"query got {max_distance.numel()} ranges for {body.batch * count} points")
            limits = max_distance.detach().to(device=self.device, dtype=torch.float32).reshape(body.batch, count)
        else:
            limits = torch.full((body.batch, count), float(max_distance), device=self.device)
        face = torch.full((body.batch, count), -1, dtype=torch.int64, device=self.device)
        barycentric = torch.zeros(body.batch, count, 3, device=self.device)
        closest, normal = queries.clone(), torch.zeros_like(barycentric)
        signed = torch.full((body.batch, count), math.inf, device=self.device)
        per_point = body.groups * 16 + 2 * body.group_size * _PER_BOUND + body.size * (_PER_BOUND + _PER_RECORD)
        chunk = max(1, self.memory_budget // (per_point * body.batch))
        for start in range(0, count, chunk):
            part = queries[:, start:start + chunk]
            hit, answer = body.nearest(part, limits[:, start:start + chunk].reshape(-1), self.memory_budget)
            b, n = hit // part.shape[1], hit % part.shape[1] + start
            face[b, n], barycentric[b, n], closest[b, n], normal[b, n], signed[b, n] = answer
        out = dict(device=points.device, dtype=points.dtype if points.is_floating_point() else torch.float32)
        lead = points.shape[:-1]
        return Nearest(
            face=self._slots[face.clamp_min(0)].where(face >= 0, -1).to(points.device).reshape(lead),
            point=closest.to(**out).reshape(*lead, 3),
            barycentric=barycentric.to(**out).reshape(*lead, 3),
            normal=normal.to(**out).reshape(*lead, 3),
            signed_distance=signed.to(**out).reshape(lead),
        )


def build_hierarchy(corners: torch.Tensor, size: int, group: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Faces (F,3,3) -> clusters of at most ``size`` faces -> groups of at most ``group`` clusters,
    as slots (H·group·size,): the face in each slot, and real (H·group·size,): False where a
    slot only pads a cluster or a group by repeating one of its faces."""
    lowers, uppers = corners.amin(dim=1), corners.amax(dim=1)
    order, cluster = _split(lowers, uppers, size)  # faces in cluster order
    index = cluster[:, None].expand(-1, 3)
    box_lowers = lowers.new_full((int(cluster[-1]) + 1, 3), math.inf).scatter_reduce(0, index, lowers[order], "amin")
    box_uppers = uppers.new_full(box_lowers.shape, -math.inf).scatter_reduce(0, index, uppers[order], "amax")
    cluster_order, group_of = _split(box_lowers, box_uppers, group)  # clusters in group order
    faces, starts = _counts_and_starts(cluster)
    members, member_starts = _counts_and_starts(group_of)
    j, s = torch.arange(group), torch.arange(size)
    clusters = cluster_order[member_starts[:, None] + torch.minimum(j, members[:, None] - 1)]  # (H,group)
    count = faces[clusters][..., None]
    slots = order[starts[clusters][..., None] + torch.minimum(s, count - 1)]  # (H,group,size)
    real = (j < members[:, None])[..., None] & (s < count)
    return slots.reshape(-1), real.reshape(-1)


def _split(lowers: torch.Tensor, uppers: torch.Tensor, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Boxes (n,3), (n,3) split top-down into compact sets of at most ``size``: an order (n,) of
    the boxes and the set (n,) of each position in it, non-decreasing.

    Every set of more than ``size`` boxes is sorted by centre along each axis and cut where
    the sum over both sides of (sets it will need) × (diagonal of its box) is least, so cuts
    fall in the gaps between body parts rather than at fixed counts. All sets of a level are
    cut at once: a segmented scan is a plain scan of values shifted by set · (a span larger
    than the body), which makes each set start a new running extreme.
    """
    lowers, uppers = lowers.double(), uppers.double()
    centres, n = (lowers + uppers) / 2, lowers.shape[0]
    span = float((uppers.amax(dim=0) - lowers.amin(dim=0)).max()) * 2 + 1
    order, segment = torch.arange(n), torch.zeros(n, dtype=torch.int64)
    while True:
        counts, starts = _counts_and_starts(segment)
        if int(counts.max()) <= size:
            return order, segment
        position = torch.arange(n) - starts[segment]
        active = (counts > size)[segment].nonzero()[:, 0]  # the positions of the sets to cut
        sets = torch.unique_consecutive(segment[active], return_inverse=True)[1]
        sizes, _ = _counts_and_starts(sets)
        within, total, members = position[active], sizes[sets], order[active]
        taken = within + 1  # cutting after each position
        costs, orders = [], []
        for axis in range(3):
            by_axis = torch.sort(centres[:, axis].index_select(0, members), stable=True).indices
            by_axis = by_axis.index_select(0, torch.sort(sets.index_select(0, by_axis), stable=True).indices)
            orders.append(members.index_select(0, by_axis))
            low, high = lowers.index_select(0, orders[-1]), uppers.index_select(0, orders[-1])
            left = _running_diagonals(low, high, sets * span)
            right = _running_diagonals(low.flip(0), high.flip(0), (sets[-1] - sets).flip(0) * span).flip(0)
            right = torch.cat([right[1:], right.new_full((1,), math.inf)])  # of the positions after
            cost = (taken + size - 1) // size * left + (total - taken + size - 1) // size * right
            costs.append(cost.where(taken < total, math.inf))
        cost, axis = torch.stack(costs).min(dim=0)
        best = cost.new_full(sizes.shape, math.inf).scatter_reduce(0, sets, cost, "amin")
        cut = torch.full_like(sizes, n).scatter_reduce(0, sets, within.where(cost == best[sets], n), "amin")
        chosen = axis[(within == cut[sets]).nonzero()[:, 0]][sets]  # the axis of each set's cut
        order[active] = torch.stack(orders).gather(0, chosen[None])[0]
        first = position == 0
        first[active] |= within == cut[sets] + 1
        segment = first.cumsum(dim=0) - 1


def _running_diagonals(lowers: torch.Tensor, uppers: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """Diagonal of the box around boxes (n,3), (n,3) from the start of their set to each
    position; ``shift`` (n,) is set · span, non-decreasing."""
    shift = shift[:, None]
    highest = (uppers + shift).cummax(dim=0).values - shift
    lowest = (lowers - shift).cummin(dim=0).values + shift
    return (highest - lowest).norm(dim=-1)


def _counts_and_starts(segment: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Sizes and first positions of the runs of a non-decreasing (n,) labelling 0, 1, ..."""
    counts = torch.bincount(segment)
    return counts, counts.cumsum(dim=0) - counts


class _Hierarchy:
    """One update's bounding shapes and face data, for B bodies.

    Flat rows: group h of body b is b·H + h, its cluster j is (b·H + h)·G + j, and that
    cluster's slot s is ((b·H + h)·G + j)·S + s. Tables and vectors are component-first,
    (features, rows) and (3, rows): on the CPU, torch runs arithmetic on long contiguous
    rows several times faster than reductions over a last axis of three.
    """

    def __init__(self, vertices: torch.Tensor, faces: torch.Tensor, slots: torch.Tensor, real: torch.Tensor,
                 size: int, group_size: int):
        """vertices (B,Vb,3) float32; faces (F,3); slots, real (H·G·S,) from ``build_hierarchy``."""
        self.batch, self.size, self.group_size = vertices.shape[0], size, group_size
        self.groups = slots.numel() // (size * group_size)
        corners = vertices.index_select(1, faces[slots].reshape(-1)).reshape(self.batch, -1, 3, 3)
        corners = corners.permute(2, 3, 0, 1).reshape(3, 3, -1)  # (corner, xyz, B·H·G·S)
        p, q, r = corners
        e0, e1, e2 = q - p, r - p, r - q
        cross = _cross(e0, e1)
        squares = _sq(e0), _sq(e1), _sq(e2)
        sliver = _sq(cross).sqrt() / sum(squares) < _SLIVER  # NaN (a point) stays, as in Warp
        real = real.repeat(self.batch)
        self.valid = real & ~sliver
        self.corners = corners.reshape(9, -1)
        self.normals = _normalize(cross)
        # Warp's ε: a fraction of the mean edge length (each face appears once among real slots).
        lengths = sum(square.sqrt() for square in squares).where(real, 0).reshape(self.batch, -1)
        self.epsilon = _TIE * lengths.sum(dim=1) / (3 * faces.shape[0])  # (B,)
        # Per slot: centre, unit normal, radius and half thickness of the smallest disc in the
        # face's plane that holds it (thick by the rounding of a needle's normal; an invalid
        # face's disc is infinitely far).
        centre = _enclosing_centre(p, q, r)
        radius = torch.stack([_sq(corner - centre) for corner in corners]).amax(dim=0).sqrt()
        thickness = torch.stack([_dot(corner - centre, self.normals).abs() for corner in corners]).amax(dim=0)
        self.discs = torch.cat([centre, self.normals, radius.where(self.valid, -math.inf)[None], thickness[None]])
        # Per cluster: a box (centre, three unit axes, half extents) around its corners, along
        # its mean normal and the corners' principal directions across it; −inf extents for
        # padding clusters, so they are never opened.
        grouped = corners.permute(1, 2, 0).reshape(3, -1, size * 3)  # (xyz, B·C, 3S)
        mean = grouped.mean(dim=-1, keepdim=True)
        offset = grouped - mean
        normal = _normalize(cross.reshape(3, -1, size).sum(dim=-1))
        helper = torch.zeros_like(normal)
        helper[0], helper[1] = normal[0].abs() < 0.9, normal[0].abs() >= 0.9  # x, or y when the normal is near x
        across = _normalize(_cross(normal, helper))
        other = _cross(normal, across)
        x, y = _dot(offset, across[..., None]), _dot(offset, other[..., None])
        angle = torch.atan2(2 * (x * y).sum(dim=-1), (x * x).sum(dim=-1) - (y * y).sum(dim=-1)) / 2
        axes = [normal, angle.cos() * across + angle.sin() * other, angle.cos() * other - angle.sin() * across]
        local = torch.stack([_dot(offset, axis[..., None]) for axis in axes])  # (3, B·C, 3S)
        lowest, highest = local.amin(dim=-1), local.amax(dim=-1)
        centre = mean[..., 0] + sum(axis * middle for axis, middle in zip(axes, (lowest + highest) / 2))
        half = ((highest - lowest) / 2).where(real.reshape(-1, size).any(dim=1), -math.inf)
        self.boxes = torch.cat([centre, *axes, half])  # (15,B·C)
        # Per group: a bounding sphere, its centre about the body's middle for the matmul.
        grouped = grouped.reshape(3, self.batch, self.groups, -1).permute(1, 2, 3, 0)  # (B,H,G·3S,3)
        centre = (grouped.amax(dim=2) + grouped.amin(dim=2)) / 2
        self.radius = (grouped - centre[:, :, None]).square().sum(dim=-1).amax(dim=-1).sqrt()  # (B,H)
        self.origin = centre.mean(dim=1, keepdim=True)  # (B,1,3)
        self.centre = centre - self.origin

    def nearest(self, queries: torch.Tensor, max_distance: torch.Tensor, budget: int):
        """Nearest faces of (B,n,3) points within (B·n,) ranges: the flat indices b·n + i of
        those that found one (K,), and their (slot (K,), barycentric (K,3), closest point (K,3), unit face normal
        (K,3), signed distance (K,))."""
        lower, nearest_centre = self.sphere_bounds(queries)  # (B·n,H), (B·n,)
        body = torch.arange(self.batch, device=queries.device).repeat_interleave(queries.shape[1])
        closest_bound, closest_group = lower.min(dim=-1)
        active = (closest_bound < max_distance + self.epsilon[body] + _SLACK).nonzero()[:, 0]  # (M,)
        max_distance = max_distance.index_select(0, active)
        lower, body = lower.index_select(0, active), body.index_select(0, active)
        points = queries.reshape(-1, 3).index_select(0, active).T.contiguous()  # (3,M)
        epsilon = self.epsilon.index_select(0, body)
        # The upper bound: the exact distance to the two faces with the nearest discs in the
        # two clusters with the nearest boxes in the groups nearest by centre and by bound.
        seed = torch.stack([nearest_centre.index_select(0, active), closest_group.index_select(0, active)], dim=1)
        seed = self._children((body * self.groups)[:, None] + seed, self.group_size).flatten(1)
        seed = seed.gather(1, self._per_point(self.box_bounds, points, seed).topk(2, dim=1, largest=False).indices)
        seed = self._children(seed, self.size).flatten(1)
        seed = seed.gather(1, self._per_point(self.disc_bounds, points, seed).topk(2, dim=1, largest=False).indices)
        seeded = self._per_point(self.distances, points, seed).amin(dim=1)
        threshold = torch.minimum(seeded, max_distance) + epsilon + _SLACK
        # Open everything below the threshold, tightening it as nearer faces turn up; keep
        # only the faces within ε of each point's nearest so far: (point row, slot, distance).
        best, kept, step = torch.full_like(threshold, math.inf), [], max(1, budget // _PER_RECORD)
        rows, groups = (lower < threshold[:, None]).nonzero().unbind(dim=1)
        groups = body.index_select(0, rows) * self.groups + groups
        for rows, clusters in self._open(points, threshold, rows, groups, self.group_size, self.box_bounds, budget):
            for rows, slots in self._open(points, threshold, rows, clusters, self.size, self.disc_bounds, budget):
                for start in range(0, rows.numel(), step):
                    row, slot = rows[start:start + step], slots[start:start + step]
                    distance = self.distances(points.index_select(1, row), slot)
                    best.scatter_reduce_(0, row, distance, "amin")
                    torch.minimum(threshold, best + epsilon + _SLACK, out=threshold)
                    near = (distance < (best + epsilon).index_select(0, row)).nonzero()[:, 0]
                    kept.append(torch.stack([row.index_select(0, near), slot.index_select(0, near)]))
                    kept.append(distance.index_select(0, near))
        row, slot = torch.cat([rows.new_empty(2, 0)] + kept[::2], dim=1)
        distance = torch.cat([best[:0]] + kept[1::2])
        found = best < max_distance
        last = torch.iinfo(torch.int64).max
        winner = slot.where(distance == best.index_select(0, row), last)
        winner = torch.full_like(body, last).scatter_reduce(0, row, winner, "amin")
        tied = ((distance < (best + epsilon).index_select(0, row)) & found.index_select(0, row)).nonzero()[:, 0]
        row, slot = row.index_select(0, tied), slot.index_select(0, tied)
        weights = self.sign_weights(points.index_select(1, row), slot, epsilon.index_select(0, row))
        pseudo_normal = torch.zeros_like(points).index_add_(1, row, weights)
        hit = found.nonzero()[:, 0]
        winner, points, pseudo_normal = winner[hit], points[:, hit], pseudo_normal[:, hit]
        a, b, c = self.corners.index_select(1, winner).reshape(3, 3, -1)
        v, w = closest_barycentric(points, a, b, c)
        u = 1 - v - w
        closest = u * a + v * b + (1 - u - v) * c  # Warp's mesh_eval_position
        outside = _dot(pseudo_normal, points - (u * a + v * b + w * c)) > 0
        signed = torch.where(outside, 1.0, -1.0) * _sq(points - closest).sqrt()
        local = winner % (self.groups * self.group_size * self.size)
        barycentric = torch.stack([u, v, 1 - u - v], dim=-1)
        return active[hit], (local, barycentric, closest.T, self.normals.index_select(1, winner).T, signed)

    def _children(self, parents: torch.Tensor, width: int) -> torch.Tensor:
        """Rows of the ``width`` children of each parent row: (...) -> (...,width)."""
        return parents[..., None] * width + torch.arange(width, device=parents.device)

    @staticmethod
    def _per_point(function, points: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        """``function`` of each point (3,M) against each of its k rows (M,k) -> (M,k)."""
        return function(points.repeat_interleave(rows.shape[1], dim=1), rows.reshape(-1)).reshape(rows.shape)

    def _open(self, points, threshold, rows, parents, width, bounds, budget):
        """Chunks of the (point row, child) pairs, from (point row, parent) pairs (P,), (P,),
        whose ``bounds`` lie below the point's threshold; each chunk's temporaries fit ``budget``."""
        step = max(1, budget // (width * _PER_BOUND))
        for start in range(0, rows.numel(), step):
            row = rows[start:start + step].repeat_interleave(width)
            child = self._children(parents[start:start + step], width).reshape(-1)
            keep = (bounds(points.index_select(1, row), child) < threshold.index_select(0, row)).nonzero()[:, 0]
            yield row.index_select(0, keep), child.index_select(0, keep)

    def sphere_bounds(self, queries: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Lower bounds (B·n,H) of the distance from (B,n,3) points to each group of their body,
        |p − centre| − radius, and the group with the nearest centre (B·n,).

        |p − c|² = |p|² + |c|² − 2 p·c as one batched matmul; its float32 rounding (a few
        1e-7 of |p|² + |c|² at most) is taken off before the square root: still a bound.
        """
        points = queries - self.origin
        squares = (points.square().sum(dim=-1)[..., None] + self.centre.square().sum(dim=-1)[:, None]) * (1 - 2e-6)
        lower = torch.baddbmm(squares, points, self.centre.transpose(1, 2), alpha=-2.0)
        nearest = lower.argmin(dim=-1).reshape(-1)
        return lower.clamp_min_(0).sqrt_().sub_(self.radius[:, None]).reshape(-1, self.groups), nearest

    def box_bounds(self, points: torch.Tensor, clusters: torch.Tensor) -> torch.Tensor:
        """Lower bounds (R,) of the distance from points (3,R) to clusters (R,): to the box that
        holds the cluster's corners."""
        box = self.boxes.index_select(1, clusters)
        offset = points - box[:3]
        excess = [(_dot(offset, box[3 + 3 * k:6 + 3 * k]).abs() - box[12 + k]).clamp_min(0) for k in range(3)]
        return sum(e.square() for e in excess).sqrt()

    def disc_bounds(self, points: torch.Tensor, slots: torch.Tensor) -> torch.Tensor:
        """Lower bounds (R,) of the distance from points (3,R) to the faces in ``slots`` (R,): to
        the smallest disc in the face's plane that holds it."""
        disc = self.discs.index_select(1, slots)
        offset = points - disc[:3]
        height = _dot(offset, disc[3:6])
        lateral = _sq(offset - height * disc[3:6]).sqrt()
        return torch.hypot((height.abs() - disc[7]).clamp_min(0), (lateral - disc[6]).clamp_min(0))

    def distances(self, points: torch.Tensor, slots: torch.Tensor) -> torch.Tensor:
        """Distance (R,) in float32, as Warp computes it, from points (3,R) to the faces in
        ``slots`` (R,); +inf for the faces Warp skips."""
        a, b, c = self.corners.index_select(1, slots).reshape(3, 3, -1)
        v, w = closest_barycentric(points, a, b, c)
        closest = (1 - v - w) * a + v * b + w * c
        return _sq(closest - points).sqrt().where(self.valid.index_select(0, slots), math.inf)

    def sign_weights(self, points: torch.Tensor, slots: torch.Tensor, epsilon: torch.Tensor) -> torch.Tensor:
        """Warp's contribution of each tied face to the inside/outside normal: (3,R), (R,), (R,) -> (3,R).

        ``mesh_query_point_sign_normal`` sums, over the faces within ε of the nearest
        distance, the unit face normal weighted by the face's angle at a corner when the
        closest point lies within ε of that corner, π when within ε of an edge's line, 2π
        otherwise: the angle-weighted pseudo-normal of the nearest feature. The point is
        outside where its offset from the closest point has a positive dot product with it.
        """
        p, q, r = self.corners.index_select(1, slots).reshape(3, 3, -1)
        v, w = closest_barycentric(points, p, q, r)
        closest = (1 - v - w) * p + v * q + w * r
        cp, cq, cr = closest - p, closest - q, closest - r
        e0, e1, e2 = q - p, r - p, r - q
        near = epsilon.square()

        def on_line(offset, edge):  # |offset × edge|² < ε²|edge|², as Warp writes it
            return _sq(offset) * _sq(edge) - _dot(edge, offset).square() < near * _sq(edge)

        weight = torch.where(on_line(cp, e0) | on_line(cq, e2) | on_line(cp, e1), math.pi, 2 * math.pi)
        u0, u1, u2 = _normalize(e0), _normalize(e1), _normalize(e2)
        angles = _angle(u0, u1), _angle(u2, -u0), _angle(-u1, -u2)  # at p, q, r
        for corner in (2, 1, 0):  # the first corner within ε wins, as in Warp
            weight = torch.where(_sq((cp, cq, cr)[corner]) < near, angles[corner], weight)
        return weight * self.normals.index_select(1, slots)


def closest_barycentric(points: torch.Tensor, a: torch.Tensor, b: torch.Tensor, c: torch.Tensor):
    """Weights (v, w) of corners b and c of the point of triangle abc closest to each point:
    (3,...) x4 -> (...), (...), component-first; the closest point is (1 − v − w)·a + v·b + w·c.

    Warp's ``closest_point_to_triangle`` (Ericson 5.1.5) region by region, in its order of
    precedence, so that on an edge or corner both pick the same weights.
    """
    ab, ac = b - a, c - a
    d1, d2 = _dot(ab, points - a), _dot(ac, points - a)
    d3, d4 = _dot(ab, points - b), _dot(ac, points - b)
    d5, d6 = _dot(ab, points - c), _dot(ac, points - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    zero, one = torch.zeros_like(d1), torch.ones_like(d1)
    inverse = 1 / _nonzero(va + vb + vc)
    v, w = vb * inverse, vc * inverse  # interior
    on = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)  # edge bc
    along = (d4 - d3) / _nonzero((d4 - d3) + (d5 - d6))
    v, w = torch.where(on, 1 - along, v), torch.where(on, along, w)
    on = (vb <= 0) & (d2 >= 0) & (d6 <= 0)  # edge ac
    v, w = torch.where(on, zero, v), torch.where(on, d2 / _nonzero(d2 - d6), w)
    on = (d6 >= 0) & (d5 <= d6)  # corner c
    v, w = torch.where(on, zero, v), torch.where(on, one, w)
    on = (vc <= 0) & (d1 >= 0) & (d3 <= 0)  # edge ab
    v, w = torch.where(on, d1 / _nonzero(d1 - d3), v), torch.where(on, zero, w)
    on = (d3 >= 0) & (d4 <= d3)  # corner b
    v, w = torch.where(on, one, v), torch.where(on, zero, w)
    on = (d1 <= 0) & (d2 <= 0)  # corner a
    return torch.where(on, zero, v), torch.where(on, zero, w)


def _enclosing_centre(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Centre of the smallest circle around each triangle abc: (3,...) x3 -> (3,...).

    The circumcentre of an acute triangle, else the midpoint of its longest side.
    """
    ab, ac = b - a, c - a
    normal = _cross(ab, ac)
    circum = a + (_cross(normal, ab) * _sq(ac) + _cross(ac, normal) * _sq(ab)) / _nonzero(2 * _sq(normal))
    bc2, ac2, ab2 = _sq(c - b), _sq(ac), _sq(ab)
    longest = torch.maximum(torch.maximum(bc2, ac2), ab2)
    midpoint = torch.where(longest == bc2, (b + c) / 2, torch.where(longest == ac2, (a + c) / 2, (a + b) / 2))
    return torch.where(longest >= bc2 + ac2 + ab2 - longest, midpoint, circum)  # obtuse or right: a side's midpoint


def _dot(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Dot products of component-first vectors: (3,...) x2 -> (...); summed in a fixed order,
    so a point's answer does not depend on how many others share its chunk."""
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Cross products of component-first vectors: (3,...) x2 -> (3,...)."""
    return torch.stack([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


def _sq(u: torch.Tensor) -> torch.Tensor:
    """Squared lengths of component-first vectors: (3,...) -> (...)."""
    return _dot(u, u)


def _nonzero(x: torch.Tensor) -> torch.Tensor:
    """x with zeros replaced by ones: a safe divisor where the quotient is not used."""
    return torch.where(x != 0, x, torch.ones_like(x))


def _normalize(u: torch.Tensor) -> torch.Tensor:
    """u/|u| for component-first vectors, zero for a zero vector (Warp's normalize): (3,...) -> (3,...)."""
    length = _sq(u).sqrt()
    return torch.where(length > 0, u / _nonzero(length), torch.zeros_like(u))


def _angle(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Angle between component-first unit vectors: (3,...) x2 -> (...)."""
    return torch.acos(_dot(u, v).clamp(-1.0, 1.0))
