"""Carrying a garment made on one body shape to another (same body mesh topology).

Binding needs Warp (a nearest-skin search); placing is torch alone, so a training pack stores
the binding and the torch-only trainer places the garment on each of its bodies.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from hyperbones.geometry.diffusion import diffuse, diffusion_steps
from hyperbones.geometry.surface import surface_points
from hyperbones.rig.garment_skinning import FREE_DISTANCE, SMOOTHING_LENGTH

if TYPE_CHECKING:
    from hyperbones.body.anny_body import Body
    from hyperbones.body.rig import BodyRig
    from hyperbones.garment.garment import Garment


@dataclass
class ShapeFollower:
    """Carries a garment made on one body to another body shape (same mesh topology).

    Each garment vertex moves by the displacement of its nearest skin point between the
    two bodies; that displacement field is then smoothed over the garment where the cloth
    hangs away from the skin, so a skirt between the legs moves with both legs instead of
    tearing (the same rule as the LBS weights). A plain nearest-point transfer folds such
    cloth where its nearest point jumps from one leg to the other.
    """

    vertices: torch.Tensor  # (V,3) the garment on the source body
    face: torch.Tensor  # (V,) nearest source face
    barycentric: torch.Tensor  # (V,3)
    source_points: torch.Tensor  # (V,3) nearest source skin points
    edges: torch.Tensor  # (E,2)
    rate: torch.Tensor  # (V,1) diffusion rate
    steps: int

    @classmethod
    def bind(cls, garment: Garment, body: Body) -> "ShapeFollower":
        from hyperbones.geometry.proximity import BodyProximity  # Warp: binding only, not placing

        proximity = BodyProximity(body.faces)
        proximity.update(body.rest_vertices)
        nearest = proximity.query(garment.vertices, max_distance=1.0)
        edges = garment.edges()
        edge_length = float((garment.vertices[edges[:, 0]] - garment.vertices[edges[:, 1]]).norm(dim=-1).mean())
        rate = 0.5 * (nearest.signed_distance.abs() / FREE_DISTANCE).clamp(0, 1)[:, None]
        return cls(garment.vertices, nearest.face.clamp_min(0), nearest.barycentric, nearest.point, edges, rate,
                   diffusion_steps(SMOOTHING_LENGTH, edge_length))

    def place(self, body: Body | BodyRig) -> torch.Tensor:
        """(V,3) the garment carried onto ``body``'s canonical pose (an Anny body or its rig)."""
        points = surface_points(body.rest_vertices, body.faces, self.face, self.barycentric)
        return self.vertices + diffuse(points - self.source_points, self.edges, self.rate, self.steps)
