"""Contact half-spaces on garment vertices: the skin patch each constrained vertex must stay
outside of, enforced by projection (the teacher's strain limiter and the runtime's edge
projection both enforce them inside their iterations)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from hyperbones.geometry.surface import Nearest, face_planes, surface_points

TRACK_REACH = 0.02  # m: vertices this near the skin before a step keep their face as a contact plane


@dataclass
class ContactPlanes:
    """Half-spaces ``(x[vertex] - point) . normal >= 0`` on some garment vertices.

    vertex: (C,) int64 garment vertex indices; point: (C,3) a point on each plane (the skin
    point moved out by the margin); normal: (C,3) unit outward normals.
    """

    vertex: torch.Tensor
    point: torch.Tensor
    normal: torch.Tensor

    @classmethod
    def tracked(cls, nearest_before: Nearest, body_after: torch.Tensor, body_faces: torch.Tensor,
                selected: torch.Tensor, margin: float, reach: float = TRACK_REACH) -> "ContactPlanes":
        """Planes for the ``selected`` (V,) vertices that ``nearest_before`` (queried on the
        body before the step) found within ``reach`` of the skin: each one's face, moved to
        the body's (Vb,3) vertices ``body_after``, shifted out by ``margin``."""
        keep = selected & (nearest_before.face >= 0) & (nearest_before.signed_distance < reach)
        vertex = keep.nonzero().squeeze(1)
        face = nearest_before.face[vertex]
        _, normal = face_planes(body_after, body_faces, face)
        skin = surface_points(body_after, body_faces, face, nearest_before.barycentric[vertex])
        return cls(vertex, skin + margin * normal.to(skin), normal.to(skin))

    @classmethod
    def nearest(cls, nearest: Nearest, selected: torch.Tensor, margin: float) -> "ContactPlanes":
        """Planes for the ``selected`` (V,) vertices at their nearest skin point now (``nearest``,
        queried on the body where it is), shifted out by ``margin``."""
        vertex = (selected & nearest.found).nonzero().squeeze(1)
        normal = nearest.normal[vertex]
        return cls(vertex, nearest.point[vertex] + margin * normal, normal)

    def __add__(self, other: "ContactPlanes") -> "ContactPlanes":
        return ContactPlanes(torch.cat([self.vertex, other.vertex]), torch.cat([self.point, other.point.to(self.point)]),
                             torch.cat([self.normal, other.normal.to(self.normal)]))

    def to(self, device: torch.device | str) -> "ContactPlanes":
        """The planes on ``device`` (itself when already there)."""
        if self.vertex.device == torch.device(device):
            return self
        return ContactPlanes(self.vertex.to(device), self.point.to(device), self.normal.to(device))

    def project(self, positions: torch.Tensor) -> torch.Tensor:
        """(V,3) -> (V,3): each constrained vertex behind its plane moved onto it along the normal."""
        if not len(self.vertex):
            return positions
        terms = (positions[self.vertex] - self.point) * self.normal
        gap = terms.mv(terms.new_ones(3))  # terms.sum(-1), at less than half its cost on the CPU
        return positions.index_add(0, self.vertex, gap.neg().clamp_min(0.0)[:, None] * self.normal)


__all__ = ["ContactPlanes", "TRACK_REACH"]
