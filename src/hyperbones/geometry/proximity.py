"""Nearest body face of garment points: a Warp BVH over the body triangles, refit every frame.

The search itself (which face is nearest, inside or outside) is discrete, so it runs in Warp
without gradients; the distances the losses differentiate are recomputed in torch from the
face it found (``signed_distance``, ``face_planes``, ``surface_points``), as HOOD does
(REFERENCE.md, "Collision").
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import warp as wp

SIGN_METHODS = ("auto", "normal", "winding")


@wp.kernel
def _nearest(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    max_distance: float,
    use_winding: int,
    faces: wp.array(dtype=wp.int32),
    barycentric: wp.array(dtype=wp.vec3),
    closest: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    signed_distances: wp.array(dtype=float),
):
    tid = wp.tid()
    p = points[tid]
    if use_winding != 0:
        query = wp.mesh_query_point_sign_winding_number(mesh, p, max_distance)
    else:
        query = wp.mesh_query_point_sign_normal(mesh, p, max_distance)
    if query.result:
        c = wp.mesh_eval_position(mesh, query.face, query.u, query.v)
        faces[tid] = query.face
        barycentric[tid] = wp.vec3(query.u, query.v, 1.0 - query.u - query.v)
        closest[tid] = c
        normals[tid] = wp.mesh_eval_face_normal(mesh, query.face)
        signed_distances[tid] = wp.sign(query.sign) * wp.length(p - c)
    else:
        faces[tid] = -1
        barycentric[tid] = wp.vec3(0.0, 0.0, 0.0)
        closest[tid] = p
        normals[tid] = wp.vec3(0.0, 0.0, 0.0)
        signed_distances[tid] = wp.inf


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


class BodyProximity:
    """A BVH over the body's triangles, built once and refit to each frame's vertices.

    Inside/outside sign (``sign``):
      - "normal": Warp's angle-weighted pseudo-normal test. Exact for a closed,
        consistently wound, non-self-intersecting surface, and cheaper than winding.
      - "winding": the generalised winding number (threshold 0.5). Stays a sensible
        inside test across holes, at the cost of a second BVH pass per point.
      - "auto" (default): "normal" when every edge is shared by exactly two faces,
        "winding" otherwise. The Anny body is closed (no boundary or non-manifold edges,
        outward winding: positive signed volume), so it gets "normal".
    On the Anny body the two differ mostly around the eyes, where the separate eyeball and
    mouth shells make the winding number call the socket "inside" while the pseudo-normal
    follows the nearest face. Warp's CPU kernels run on one thread; on CUDA a query is one
    kernel launch. Agreement and costs: docs/experiments/*-body-proximity-sign.md.
    """

    def __init__(self, faces: torch.Tensor, device: str | torch.device | None = "cpu", sign: str = "auto"):
        """faces: (F,3) body triangles (counter-clockwise seen from outside); device: where Warp runs (None: faces' device)."""
        from hyperbones.geometry.warp_setup import init_warp_quietly

        if sign not in SIGN_METHODS:
            raise ValueError(f"sign must be one of {SIGN_METHODS}, got {sign!r}")
        init_warp_quietly()
        self.device = torch.device(device) if device is not None else faces.device
        if self.device.type == "cuda" and self.device.index is None:
            self.device = torch.device("cuda", torch.cuda.current_device())
        self.faces = faces.to(device=self.device, dtype=torch.int64)
        self.sign = sign if sign != "auto" else ("normal" if is_closed_surface(self.faces) else "winding")
        self._indices = self.faces.to(torch.int32).reshape(-1).contiguous()
        self._points: torch.Tensor | None = None  # Warp's mesh reads this memory in place
        self._mesh: wp.Mesh | None = None

    def update(self, body_vertices: torch.Tensor) -> None:
        """Move the body to ``body_vertices`` (Vb,3): builds the BVH the first time, then refits it."""
        vertices = body_vertices.detach().to(device=self.device, dtype=torch.float32)
        rebuild = self._mesh is None or self._points is None or self._points.shape != vertices.shape
        if rebuild:
            self._points = vertices.contiguous().clone()
        else:
            self._points.copy_(vertices)
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)  # torch wrote the points on its stream; Warp reads on its own
        if rebuild:
            self._mesh = wp.Mesh(
                points=_vec3(self._points),
                indices=wp.from_torch(self._indices, dtype=wp.int32),
                support_winding_number=self.sign == "winding",
            )
        else:
            self._mesh.refit()

    def query(self, points: torch.Tensor, max_distance: float = 1.0) -> Nearest:
        """Nearest body face of each of ``points`` (N,3) within ``max_distance`` metres.

        Returns tensors on ``points``' device, floats in its dtype; (...,N,3) points give
        (...,N)-shaped fields.
        """
        if self._mesh is None:
            raise RuntimeError("BodyProximity.query called before update(body_vertices)")
        queries = points.detach().to(device=self.device, dtype=torch.float32).reshape(-1, 3).contiguous()
        count = queries.shape[0]
        face = torch.empty(count, dtype=torch.int32, device=self.device)
        barycentric = torch.empty(count, 3, dtype=torch.float32, device=self.device)
        closest = torch.empty_like(barycentric)
        normal = torch.empty_like(barycentric)
        signed = torch.empty(count, dtype=torch.float32, device=self.device)
        if count:
            stream = wp.stream_from_torch(self.device) if self.device.type == "cuda" else None
            wp.launch(
                _nearest,
                dim=count,
                inputs=[self._mesh.id, _vec3(queries), float(max_distance), int(self.sign == "winding")],
                outputs=[wp.from_torch(face), _vec3(barycentric), _vec3(closest), _vec3(normal), wp.from_torch(signed)],
                device=wp.device_from_torch(self.device),
                stream=stream,
            )
            if stream is None:
                wp.synchronize_device("cpu")
        out = dict(device=points.device, dtype=points.dtype if points.is_floating_point() else torch.float32)
        lead = points.shape[:-1]
        return Nearest(
            face=face.to(device=points.device, dtype=torch.int64).reshape(lead),
            point=closest.to(**out).reshape(*lead, 3),
            barycentric=barycentric.to(**out).reshape(*lead, 3),
            normal=normal.to(**out).reshape(*lead, 3),
            signed_distance=signed.to(**out).reshape(lead),
        )


def _vec3(tensor: torch.Tensor) -> wp.array:
    """A zero-copy Warp view of an (N,3) float32 tensor."""
    return wp.from_torch(tensor, dtype=wp.vec3)


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
