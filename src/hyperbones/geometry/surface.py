"""Points against a body surface in plain torch: the nearest-face record a proximity query
returns, face planes, skin points by barycentric coordinates, the exact closest point on a
face, plane distances and the push-out to a margin.

No Warp here: the search itself (``geometry.proximity.BodyProximity``, a Warp BVH) is the
one part that needs it, so everything that only uses a query's answer, the per-frame
runtime included, runs where torch alone is installed.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class Nearest:
    """Nearest body face of N points (no gradients).

    face: (N,) int64 face index, −1 where no face lies within ``max_distance``.
    point: (N,3) closest point on the body (the query point itself on a miss).
    barycentric: (N,3) weights of the face's three vertices giving ``point``.
    normal: (N,3) unit face normal, outward for an outward-wound body (zero on a miss).
    signed_distance: (N,) |point − query|, negative inside the body (+inf on a miss).
    """

    face: torch.Tensor
    point: torch.Tensor
    barycentric: torch.Tensor
    normal: torch.Tensor
    signed_distance: torch.Tensor

    @property
    def found(self) -> torch.Tensor:
        """(N,) bool: a face was found within range."""
        return self.face >= 0

    def with_rows(self, index: torch.Tensor, other: "Nearest") -> "Nearest":
        """This record with rows ``index`` (M,) replaced by ``other``'s M rows."""
        return Nearest(*(getattr(self, name).index_copy(0, index, getattr(other, name).to(getattr(self, name)))
                         for name in ("face", "point", "barycentric", "normal", "signed_distance")))


def is_closed_surface(faces: torch.Tensor) -> bool:
    """True when every undirected edge of the (F,3) triangles is shared by exactly two faces."""
    edges = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).sort(dim=-1).values
    counts = torch.unique(edges, dim=0, return_counts=True)[1]
    return bool((counts == 2).all())


def face_planes(
    body_vertices: torch.Tensor, faces: torch.Tensor, face: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """A point (vertex 0) and the unit normal of each chosen face, differentiable.

    body_vertices: (...,Vb,3); faces: (F,3); face: (N,) indices, −1 for none.
    Returns origin (...,N,3) and normal (...,N,3); both are zero where face is −1, so
    ``collision_energy`` skips those points.
    """
    valid = (face >= 0)[:, None]
    corners = faces[face.clamp_min(0)].to(body_vertices.device)
    v0, v1, v2 = (body_vertices[..., corners[:, c], :] for c in range(3))
    normal = torch.linalg.cross(v1 - v0, v2 - v0, dim=-1)
    normal = normal / normal.square().sum(-1, keepdim=True).clamp_min(1e-30).sqrt()
    return torch.where(valid, v0, torch.zeros_like(v0)), torch.where(valid, normal, torch.zeros_like(normal))


def surface_points(
    body_vertices: torch.Tensor, faces: torch.Tensor, face: torch.Tensor, barycentric: torch.Tensor
) -> torch.Tensor:
    """The body points with barycentric coordinates (N,3) on faces (N,), posed by (...,Vb,3) -> (...,N,3).

    Use ``Nearest.face``/``Nearest.barycentric`` from frame t to follow the same skin point
    to another frame (friction's moving body point).
    """
    corners = faces[face.clamp_min(0)].to(body_vertices.device)
    stacked = torch.stack([body_vertices[..., corners[:, c], :] for c in range(3)], dim=-2)  # (...,N,3,3)
    return (barycentric.to(body_vertices)[..., None] * stacked).sum(-2)


def closest_points_on_faces(
    points: torch.Tensor, body_vertices: torch.Tensor, faces: torch.Tensor, face: torch.Tensor
) -> torch.Tensor:
    """The closest point of each chosen face's triangle to each point, in the points' dtype:
    (N,3), (Vb,3), (F,3), (N,) -> (N,3) (face −1 reads as face 0; mask it yourself).

    ``BodyProximity`` answers in float32, whose barycentric coordinates place the skin
    point only to ~1e-7 m: enough to pick the face, too coarse for an energy that a
    double-precision solver compares to 1e-9 J (the drape's line search). This redoes the
    projection onto the face it picked in full precision (Voronoi regions of the triangle:
    its vertices, edges, interior; Ericson, Real-Time Collision Detection, 5.1.5).
    """
    corners = faces[face.clamp_min(0)].to(body_vertices.device)
    a, b, c = (body_vertices[corners[:, k]].to(points) for k in range(3))

    def dot(u, v):
        return (u * v).sum(-1, keepdim=True)

    ab, ac, ap, bp, cp = b - a, c - a, points - a, points - b, points - c
    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    def ratio(numerator, denominator):
        return numerator / torch.where(denominator.abs() > 0, denominator, torch.ones_like(denominator))

    total = va + vb + vc
    result = a + ab * ratio(vb, total) + ac * ratio(vc, total)  # interior
    # Later regions take precedence: the tests are exclusive on a proper triangle, and on a
    # degenerate one the vertex and edge answers are the safe ones.
    on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    result = torch.where(on_bc, b + (c - b) * ratio(d4 - d3, (d4 - d3) + (d5 - d6)), result)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    result = torch.where(on_ac, a + ac * ratio(d2, d2 - d6), result)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    result = torch.where(on_ab, a + ab * ratio(d1, d1 - d3), result)
    result = torch.where((d6 >= 0) & (d5 <= d6), c, result)
    result = torch.where((d3 >= 0) & (d4 <= d3), b, result)
    return torch.where((d1 <= 0) & (d2 <= 0), a, result)


def signed_distance(
    points: torch.Tensor, body_vertices: torch.Tensor, faces: torch.Tensor, face: torch.Tensor
) -> torch.Tensor:
    """Signed distance of points to the plane of their given body face: (...,N,3) -> (...,N).

    body_vertices: (...,Vb,3); faces: (F,3); face: (N,) from ``BodyProximity.query``
    (+inf where face is −1). Differentiable in points and body vertices.

    The plane, not the triangle: d = (p − v0)·n̂ is smooth (the distance to a triangle has
    kinks across its edges) and it is HOOD's collision distance. It equals the true signed
    distance when the closest point lies inside the face, and its magnitude is never larger
    than the true distance; near edges and vertices they differ at second order in the
    offset along the surface.
    """
    origin, normal = face_planes(body_vertices, faces, face)
    distance = ((points - origin) * normal).sum(-1)
    return torch.where(face >= 0, distance, torch.full_like(distance, float("inf")))


def push_outside(points: torch.Tensor, nearest: Nearest, margin: float, movable: torch.Tensor | None = None) -> torch.Tensor:
    """Points (N,3) closer to the body than ``margin`` (or inside it) moved to ``margin`` outside
    their nearest point along its face normal; ``movable`` (N,) bool limits which may move."""
    close = nearest.found & (nearest.signed_distance < margin)
    if movable is not None:
        close = close & movable
    moved = nearest.point + margin * nearest.normal
    return torch.where(close[:, None], moved.to(points), points)


def push_outside_two(points: torch.Tensor, nearest: Nearest, margin: float, last_normal: torch.Tensor,
                     last_target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Points (N,3) that a push-out put at ``last_target`` (N,3), ``margin`` off a face with unit
    normal ``last_normal`` (N,3), and that are inside ``nearest``'s faces now, moved out of both,
    so that pushing off one face at a time does not bounce them between two for dozens of rounds:

    - a crease (the faces at an angle): to ``margin`` outside the new face, and where that would
      cross back behind the last face's offset plane, to the nearest point where the two offset
      planes meet;
    - two body parts pressed together (the faces facing each other, cosine below -0.8, as where
      an arm skinned against the chest leaves a gap under the margin): halfway between the two
      skin points, the farthest it can be from both; these are ``trapped``: no push can do better;
    - faces within ~18 degrees of parallel: the plain push.

    Returns the (N,3) moved points (the targets a next push is checked against) and (N,) bool
    trapped."""
    target = nearest.point + margin * nearest.normal
    cosine = (last_normal * nearest.normal).sum(1)
    trapped = cosine < -0.8
    crosses = (last_normal * (target - last_target)).sum(1) < 0
    corner = crosses & ~trapped & (1.0 - cosine * cosine > 0.1)
    # On both planes: points + a n_last + b n_new with n_last.(y - last_target) = 0 and n_new.(y - target) = 0.
    to_last = (last_normal * (last_target - points)).sum(1)
    to_new = (nearest.normal * (target - points)).sum(1)
    det = (1.0 - cosine * cosine).clamp_min(0.1)
    a = (to_last - cosine * to_new) / det
    b = (to_new - cosine * to_last) / det
    on_both = points + a[:, None] * last_normal + b[:, None] * nearest.normal
    between = 0.5 * (last_target - margin * last_normal + nearest.point)
    moved = torch.where(trapped[:, None], between, torch.where(corner[:, None], on_both, target)).to(points)
    return moved, trapped


def search_ranges(points: torch.Tensor, skin: torch.Tensor | None, max_distance: float) -> torch.Tensor | float:
    """How far a nearest-face search need look from each of (N,3) ``points``: ``max_distance``,
    or less where a point of the body's surface as it is now (N,3; NaN: none known) is nearer,
    padded by float32's rounding so that the nearest face is never cut off. The answer of a
    search so bounded is that of the full one (the nearest face lies within the distance to
    any skin point), and it visits less of the tree."""
    if skin is None:
        return max_distance
    bound = (points - skin).norm(dim=1) * (1.0 + 1e-5) + 1e-6
    return torch.where(bound < max_distance, bound, torch.full_like(bound, max_distance))


def found_points(nearest: Nearest) -> torch.Tensor:
    """(N,3) the skin points a query found (NaN where it found none)."""
    return torch.where(nearest.found[:, None], nearest.point, torch.nan)


def carried_points(nearest: Nearest, body_vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(N,3) the skin points a query found, carried to the body posed as (Vb,3) ``body_vertices``
    (same face, same barycentric coordinates; NaN where it found none): skin points for
    ``search_ranges`` after the body has moved."""
    points = surface_points(body_vertices, faces, nearest.face, nearest.barycentric)
    return torch.where(nearest.found[:, None], points, torch.nan)
