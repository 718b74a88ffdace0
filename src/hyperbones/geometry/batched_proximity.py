"""Nearest body face for several garments, each against its own body, asked as one flat query.

A batch of B training episodes is one garment on one body (``training.episode_batch``): the
garments' N vertices one after another, and the B bodies' vertices and faces one after
another (a "multi-body", (B·Vb,3) and (B·F,3)). A plain search over the multi-body would
let a garment find the faces of another episode's body. ``TorchProximity`` already answers
B bodies at once, each for its own row of points; this adapter lays the flat points out
as those rows (padded to the longest garment), and the answers back out flat, with faces
numbered in the multi-body's face list, so code written for one body (``constrain_step``,
``ContactPlanes``, ``build_graph``) runs on a batch unchanged.
"""

from __future__ import annotations

import torch

from hyperbones.geometry.search import search_backend
from hyperbones.geometry.surface import Nearest
from hyperbones.geometry.torch_proximity import TorchProximity


def multi_body_faces(faces: torch.Tensor, num_bodies: int, num_body_vertices: int) -> torch.Tensor:
    """One body's faces (F,3) -> the multi-body's (B·F,3): body b's indices offset by b·Vb."""
    shifts = torch.arange(num_bodies, device=faces.device) * num_body_vertices
    return (faces[None] + shifts[:, None, None]).reshape(-1, 3)


class BatchedProximity:
    """B bodies of one mesh searched at once, with the one-body API of ``BodyProximity``.

    ``update`` takes the multi-body (B·Vb,3) or (B,Vb,3); ``query`` takes the B garments'
    points flat, (N,3), and answers flat; ``faces`` is the multi-body's (B·F,3), body b's
    faces offset by b·Vb, which the answers' ``face`` indexes (−1: none in range).
    """

    sign = TorchProximity.sign

    def __init__(self, faces: torch.Tensor, num_body_vertices: int, vertex_offsets: torch.Tensor,
                 device: str | torch.device | None = "cpu", search: str = "auto", **search_options):
        """faces: (F,3) one body's triangles; num_body_vertices: Vb, the vertices of one body;
        vertex_offsets: (B+1,) where each garment's points start in the flat points (the last
        is N); device: where the search runs (None: faces'); search: "auto", "warp" or "torch"
        (``geometry.search.search_backend``: Warp's BVH per body on a CPU that has it, 4–5×
        faster there; the torch search over all bodies at once elsewhere); search_options:
        ``TorchProximity``'s cluster_size, group_size, memory_budget."""
        self.search = TorchProximity(faces, device, **search_options)
        self.device = self.search.device
        self.backend = search_backend(search, self.device)
        self._bodies: list | None = None  # Warp: one search per body, made on the first update
        offsets = vertex_offsets.to(device=self.device, dtype=torch.int64)
        counts = offsets.diff()
        if offsets.dim() != 1 or len(counts) < 1 or bool((counts < 1).any()) or int(offsets[0]) != 0:
            raise ValueError(f"vertex_offsets must be B+1 >= 2 rising starts from 0 (every garment with a vertex), "
                             f"got {offsets.tolist()}")
        self.num_bodies, self.num_body_vertices = len(counts), int(num_body_vertices)
        self.num_points, self.row_length = int(offsets[-1]), int(counts.max())
        self._sizes = counts.tolist()
        num_faces = self.search.faces.shape[0]
        bodies = torch.arange(self.num_bodies, device=self.device)
        self.faces = multi_body_faces(self.search.faces, self.num_bodies, self.num_body_vertices)
        # Row b slot j holds point offsets[b] + j, or (a padding slot) the garment's last point again.
        slot = torch.arange(self.row_length, device=self.device)
        self._sources = (offsets[:-1, None] + torch.minimum(slot, counts[:, None] - 1)).reshape(-1)  # (B·Nmax,)
        garment = bodies.repeat_interleave(counts)  # (N,)
        self._slots = garment * self.row_length + torch.arange(self.num_points, device=self.device) - offsets[garment]
        self._face_offsets = garment * num_faces

    def update(self, body_vertices: torch.Tensor) -> None:
        """Move the B bodies to ``body_vertices``: the multi-body (B·Vb,3), or (B,Vb,3)."""
        expected = (self.num_bodies * self.num_body_vertices, 3)
        if body_vertices.reshape(-1, 3).shape != expected:
            raise ValueError(f"body_vertices {tuple(body_vertices.shape)} must hold {self.num_bodies} bodies "
                             f"of {self.num_body_vertices} vertices")
        bodies = body_vertices.reshape(self.num_bodies, self.num_body_vertices, 3)
        if self.backend == "torch":
            self.search.update(bodies)
            return
        if self._bodies is None:
            from hyperbones.geometry.proximity import BodyProximity

            self._bodies = [BodyProximity(self.search.faces, self.device, sign=self.sign)
                            for _ in range(self.num_bodies)]
        for search, body in zip(self._bodies, bodies):
            search.update(body)

    def query(self, points: torch.Tensor, max_distance: float | torch.Tensor = 1.0) -> Nearest:
        """Nearest face of each of the B garments' ``points`` (N,3) on its own body, within
        ``max_distance`` m (one range, or (N,) one per point); fields (N,...) on ``points``'
        device, floats in its dtype, ``face`` in the multi-body's numbering."""
        if points.shape != (self.num_points, 3):
            raise ValueError(f"points {tuple(points.shape)} must be the batch's ({self.num_points}, 3)")
        if self.backend == "warp":
            return self._query_each(points, max_distance)
        rows = points.detach().to(self.device).index_select(0, self._sources)
        if isinstance(max_distance, torch.Tensor):
            if max_distance.numel() != self.num_points:
                raise ValueError(f"query got {max_distance.numel()} ranges for {self.num_points} points")
            max_distance = max_distance.detach().to(self.device).reshape(-1).index_select(0, self._sources)
        answer = self.search.query(rows.reshape(self.num_bodies, self.row_length, 3), max_distance)
        face = answer.face.reshape(-1).index_select(0, self._slots)
        face = torch.where(face >= 0, face + self._face_offsets, face)
        fields = [getattr(answer, name).flatten(0, 1).index_select(0, self._slots)
                  for name in ("point", "barycentric", "normal", "signed_distance")]
        return Nearest(*(value.to(points.device) for value in [face, *fields]))

    def _query_each(self, points: torch.Tensor, max_distance: float | torch.Tensor) -> Nearest:
        """``query`` by one Warp search per body over its garment's points."""
        if self._bodies is None:
            raise RuntimeError("BatchedProximity.query called before update(body_vertices)")
        sizes = self._sizes
        ranges = (max_distance.reshape(-1).split(sizes) if isinstance(max_distance, torch.Tensor)
                  else [max_distance] * len(sizes))
        answers = [search.query(part, limit) for search, part, limit in zip(self._bodies, points.split(sizes), ranges)]
        face = torch.cat([answer.face for answer in answers]).to(self._face_offsets.device)
        face = torch.where(face >= 0, face + self._face_offsets, face).to(points.device)
        return Nearest(face, *(torch.cat([getattr(answer, name) for answer in answers])
                               for name in ("point", "barycentric", "normal", "signed_distance")))


__all__ = ["BatchedProximity", "multi_body_faces"]
