"""The LBS baseline: the garment skinned to the body skeleton.

Weights come from the nearest body surface point (its vertices' skin weights, blended
barycentrically) and are then diffused over the garment's own edges where the cloth hangs
away from the body, so that a skirt blends both thighs instead of tearing between the
legs, while cloth lying on the skin keeps the skin's weights and moves with it.
"""

from __future__ import annotations

import torch

from hyperbones.body.anny_body import Body
from hyperbones.garment.garment import Garment
from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.geometry.proximity import BodyProximity

SMOOTHING_LENGTH = 0.15  # metres the weights are diffused over
FREE_DISTANCE = 0.05  # cloth this far from the skin (or more) diffuses fully


def garment_skin_weights(garment: Garment, body: Body, smoothing_length: float = SMOOTHING_LENGTH) -> torch.Tensor:
    """(V,31) skinning weights of the canonical garment (rows sum to 1)."""
    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    nearest = proximity.query(garment.vertices, max_distance=1.0)
    corners = body.faces[nearest.face.clamp(min=0)]  # (V,3)
    weights = (nearest.barycentric[..., None] * body.skin_weights[corners]).sum(1)
    edges = garment.edges()
    n = garment.num_vertices
    index = torch.cat([edges, edges.flip(1)]).T
    adjacency = torch.sparse_coo_tensor(index, torch.ones(index.shape[1]), (n, n),
                                        check_invariants=False).coalesce()
    degree = torch.sparse.sum(adjacency, 1).to_dense().clamp(min=1)[:, None]
    edge_length = float((garment.vertices[edges[:, 0]] - garment.vertices[edges[:, 1]]).norm(dim=-1).mean())
    # Half-step Jacobi diffusion spreads about one edge length per sqrt(2 steps).
    steps = int(min(500, max(1, 2 * (smoothing_length / max(edge_length, 1e-4)) ** 2)))
    rate = 0.5 * (nearest.signed_distance.abs() / FREE_DISTANCE).clamp(0, 1)[:, None]
    for _ in range(steps):
        weights = (1 - rate) * weights + rate * torch.sparse.mm(adjacency, weights) / degree
    return weights / weights.sum(1, keepdim=True)


class LbsMethod:
    """Per-frame garment positions by linear blend skinning (no dynamics)."""

    name = "lbs"

    def __init__(self, garment: Garment, body: Body):
        self.rest_vertices = garment.vertices
        self.weights = garment_skin_weights(garment, body)

    def run(self, skinning_transforms: torch.Tensor) -> torch.Tensor:
        """(T,31,4,4) body skinning transforms -> (T,V,3) garment positions."""
        return linear_blend_skinning(self.rest_vertices, self.weights, skinning_transforms)
