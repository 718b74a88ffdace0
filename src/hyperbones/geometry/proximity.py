"""Nearest body face of garment points: a Warp BVH over the body triangles, refit every frame.

The search itself (which face is nearest, inside or outside) is discrete, so it runs in Warp
without gradients; the distances the losses differentiate are recomputed in torch from the
face it found (``geometry.surface``: ``signed_distance``, ``face_planes``, ``surface_points``), as HOOD does
(REFERENCE.md, "Collision"). The runtime's push-out, searches and pushes together, also runs
here as one launch (``BodyProximity.push_out``): one vertex a thread, no tensor operations
between its rounds.
"""

from __future__ import annotations

import torch
import warp as wp

from hyperbones.geometry.surface import Nearest, is_closed_surface

SIGN_METHODS = ("auto", "normal", "winding")


@wp.func
def _nearest_record(mesh: wp.uint64, p: wp.vec3, max_distance: float, use_winding: int):
    """One point's nearest face within ``max_distance``: (found, face, barycentric, closest point,
    face normal, signed distance); where none lies within range: (False, −1, 0, p, 0, +inf)."""
    if use_winding != 0:
        query = wp.mesh_query_point_sign_winding_number(mesh, p, max_distance)
    else:
        query = wp.mesh_query_point_sign_normal(mesh, p, max_distance)
    if query.result:
        c = wp.mesh_eval_position(mesh, query.face, query.u, query.v)
        return (True, query.face, wp.vec3(query.u, query.v, 1.0 - query.u - query.v), c,
                wp.mesh_eval_face_normal(mesh, query.face), wp.sign(query.sign) * wp.length(p - c))
    return False, -1, wp.vec3(0.0, 0.0, 0.0), p, wp.vec3(0.0, 0.0, 0.0), wp.inf


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
    _found, face, weights, point, normal, signed = _nearest_record(mesh, points[tid], max_distances[tid], use_winding)
    faces[tid] = face
    barycentric[tid] = weights
    closest[tid] = point
    normals[tid] = normal
    signed_distances[tid] = signed


@wp.func
def _bounded(p: wp.vec3, skin: wp.vec3, max_distance: float):
    """``surface.search_ranges`` for one point: the distance to a skin point (NaN: none),
    padded for float32 rounding, where it is below ``max_distance``."""
    bound = wp.length(p - skin) * (1.0 + 1.0e-5) + 1.0e-6
    if wp.isnan(bound) or bound >= max_distance:
        return max_distance
    return bound


@wp.kernel(enable_backward=False)
def _push_out(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    skin: wp.array(dtype=wp.vec3),
    query_distance: float,
    again_distance: float,
    margin: float,
    rounds: int,
    stuck_step: float,
    use_winding: int,
    pushed: wp.array(dtype=wp.vec3),
    faces: wp.array(dtype=wp.int32),
    barycentric: wp.array(dtype=wp.vec3),
    closest: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    signed_distances: wp.array(dtype=float),
):
    """``push_out.BodyContact._push_out`` for one point a thread: its nearest face (searched
    no farther than its skin point), the push to the margin, and up to ``rounds`` − 1 more
    pushes while it is inside a face (``surface.push_outside_two``: a crease's two planes, or
    halfway between two parts pressed together), stopping where a push no longer moves it."""
    tid = wp.tid()
    p = points[tid]
    found, face, weights, point, normal, signed = _nearest_record(
        mesh, p, _bounded(p, skin[tid], query_distance), use_winding)
    faces[tid] = face
    barycentric[tid] = weights
    closest[tid] = point
    normals[tid] = normal
    signed_distances[tid] = signed
    if found and signed < margin:
        p = point + margin * normal
        last_normal = normal
        last_target = p
        for _ in range(rounds - 1):
            inside, _face, _weights, point2, normal2, signed2 = _nearest_record(
                mesh, p, _bounded(p, point, again_distance), use_winding)
            if not (inside and signed2 < 0.0):
                break
            target = point2 + margin * normal2
            cosine = wp.dot(last_normal, normal2)
            trapped = cosine < -0.8
            moved = target
            if trapped:
                moved = 0.5 * (last_target - margin * last_normal + point2)
            elif wp.dot(last_normal, target - last_target) < 0.0 and 1.0 - cosine * cosine > 0.1:
                to_last = wp.dot(last_normal, last_target - p)
                to_new = wp.dot(normal2, target - p)
                det = wp.max(1.0 - cosine * cosine, 0.1)
                a = (to_last - cosine * to_new) / det
                b = (to_new - cosine * to_last) / det
                moved = p + a * last_normal + b * normal2
            stuck = trapped or wp.length(moved - p) < stuck_step
            p = moved
            if stuck:
                break
            last_normal = normal2
            last_target = moved
    pushed[tid] = p


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
        count = points[..., 0].numel()
        if isinstance(max_distance, torch.Tensor):
            ranges = max_distance.detach().reshape(-1)
            if ranges.shape[0] != count:
                raise ValueError(f"query got {ranges.shape[0]} ranges for {count} points")
        buffers = self._loaded("query", points)
        if isinstance(max_distance, torch.Tensor):
            buffers.ranges[:count].copy_(ranges)
        else:
            buffers.ranges[:count].fill_(float(max_distance))
        self._run(buffers.launch, count)
        return self._record(buffers, count, points)

    def push_out(self, points: torch.Tensor, skin: torch.Tensor | None, query_distance: float,
                 again_distance: float, margin: float, rounds: int, stuck_step: float) -> tuple[torch.Tensor, Nearest]:
        """(N,3) points with every one inside the body or within ``margin`` moved out to the
        margin, and their first search's ``Nearest``: ``push_out.BodyContact._push_out`` in one
        launch (the same pushes, one point a thread). skin: (N,3) a skin point of each (NaN:
        none) bounding its first search, else ``query_distance``; again_distance: the range of
        the searches after a push (bounded by the first search's skin point); rounds: pushes at
        most; stuck_step: a push moving a point less than this is its last."""
        count = points[..., 0].numel()
        buffers = self._loaded("push_out", points)
        if skin is None:
            buffers.skin[:count].fill_(float("nan"))
        else:
            buffers.skin[:count].copy_(skin.detach().reshape(-1, 3))
        settings = (float(query_distance), float(again_distance), float(margin), int(rounds), float(stuck_step))
        if settings != buffers.push_settings:  # the same every frame: set on the recorded launch once
            for index, value in enumerate(settings, start=3):
                buffers.push_launch.set_param_at_index(index, value)
            buffers.push_settings = settings
        self._run(buffers.push_launch, count)
        pushed = buffers.pushed[:count].to(device=points.device, dtype=points.dtype, copy=True)
        return pushed.reshape(points.shape), self._record(buffers, count, points)

    def _loaded(self, caller: str, points: torch.Tensor) -> "_QueryBuffers":
        """The query buffers, at least as many rows as (...,3) ``points``, with them copied in."""
        if self._mesh is None:
            raise RuntimeError(f"BodyProximity.{caller} called before update(body_vertices)")
        queries = points.detach().to(device=self.device, dtype=torch.float32).reshape(-1, 3)
        buffers = self._buffers_for(queries.shape[0])
        buffers.points[:queries.shape[0]].copy_(queries)
        return buffers

    def _run(self, launch, count: int) -> None:
        """A recorded launch over its first ``count`` rows: on torch's stream on CUDA, waited for on the CPU."""
        if not count:
            return
        launch.set_dim(count)
        if self.device.type == "cuda":
            launch.launch(stream=wp.stream_from_torch(self.device))
        else:
            launch.launch()
            wp.synchronize_device("cpu")

    def _record(self, buffers: "_QueryBuffers", count: int, points: torch.Tensor) -> Nearest:
        """The first ``count`` rows of the buffers' outputs as a ``Nearest`` shaped and typed like
        ``points`` (copies: the buffers are the next query's)."""
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
        self.skin = torch.zeros(capacity, 3, **rows)
        self.pushed = torch.zeros(capacity, 3, **rows)
        self.push_settings: tuple | None = None  # the settings last set on push_launch
        self.push_launch = wp.launch(  # ``push_out``'s; its settings are set when they change
            _push_out,
            dim=capacity,
            inputs=[mesh_id, _vec3(self.points), _vec3(self.skin), 0.0, 0.0, 0.0, 1, 0.0, int(winding)],
            outputs=[_vec3(self.pushed), wp.from_torch(self.face), _vec3(self.barycentric), _vec3(self.closest),
                     _vec3(self.normal), wp.from_torch(self.signed)],
            device=wp.device_from_torch(device),
            record_cmd=True,
        )


def _vec3(tensor: torch.Tensor) -> wp.array:
    """A zero-copy Warp view of an (N,3) float32 tensor."""
    return wp.from_torch(tensor, dtype=wp.vec3)
