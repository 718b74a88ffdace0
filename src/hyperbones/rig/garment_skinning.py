"""The LBS baseline: the garment skinned to the body skeleton.

Weights come from the nearest body surface point (its vertices' skin weights, blended
barycentrically) and are then diffused over the garment's own edges where the cloth hangs
away from the body, so that a skirt blends both thighs instead of tearing between the
legs, while cloth lying on the skin keeps the skin's weights and moves with it.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch

from hyperbones.body.anny_body import Body, PosedBody
from hyperbones.garment.garment import Garment
from hyperbones.geometry.diffusion import diffuse, diffusion_steps
from hyperbones.geometry.lbs import linear_blend_skinning

SMOOTHING_LENGTH = 0.15  # metres the weights are diffused over
FREE_DISTANCE = 0.05  # cloth this far from the skin (or more) diffuses fully
TEAR_JUMP = 0.3  # L1 change of the weights across one edge that marks a tear line
TEAR_BAND = 0.05  # m: cloth this close (along the garment) to a tear line diffuses fully
TEAR_PASSES = 2  # further diffusions of what is still torn after the first


def garment_skin_weights(garment: Garment, body: Body, smoothing_length: float = SMOOTHING_LENGTH) -> torch.Tensor:
    """(V,31) skinning weights of the canonical garment (rows sum to 1)."""
    from hyperbones.geometry.proximity import BodyProximity  # Warp, here only: its constants travel without it

    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    nearest = proximity.query(garment.vertices, max_distance=1.0)
    corners = body.faces[nearest.face.clamp(min=0)]  # (V,3)
    weights = (nearest.barycentric[..., None] * body.skin_weights[corners]).sum(1)
    edges = garment.edges()
    edge_length = float((garment.vertices[edges[:, 0]] - garment.vertices[edges[:, 1]]).norm(dim=-1).mean())
    rate = 0.5 * (nearest.signed_distance.abs() / FREE_DISTANCE).clamp(0, 1)
    # Cloth touching two body parts at once (a skirt's front across both thighs) takes its
    # nearest-skin weights from one part or the other, and LBS would tear it along that
    # line: a band of TEAR_BAND metres around such a line diffuses fully as well.
    steps = diffusion_steps(smoothing_length, edge_length)
    tear = _tear_band(weights, edges, edge_length)
    rate = torch.where(tear, torch.full_like(rate, 0.5), rate)[:, None]
    weights = diffuse(weights, edges, rate, steps)
    # Where cloth that diffuses meets cloth on the skin that hardly does (a long skirt's hem
    # lying on the feet), the diffusion itself can leave a tear: only the band around what is
    # still torn diffuses again, everything else keeps its weights, pinned cloth (a waistband,
    # which the teacher moves by these weights) included.
    pinned = torch.zeros(len(weights), dtype=torch.bool)
    pinned[garment.pinned] = True
    for _ in range(TEAR_PASSES):
        tear = _tear_band(weights, edges, edge_length) & ~pinned
        if not bool(tear.any()):
            break
        weights = diffuse(weights, edges, 0.5 * tear[:, None].to(weights.dtype), steps)
    return weights / weights.sum(1, keepdim=True)


def _tear_band(weights: torch.Tensor, edges: torch.Tensor, edge_length: float) -> torch.Tensor:
    """(V,) bool: the vertices within TEAR_BAND (along the garment's (E,2) edges, of mean length
    ``edge_length``) of an edge across which the (V,J) weights change by more than TEAR_JUMP."""
    tear = torch.zeros(len(weights), dtype=torch.bool)
    torn = (weights[edges[:, 0]] - weights[edges[:, 1]]).abs().sum(1) > TEAR_JUMP
    tear[edges[torn].reshape(-1)] = True
    for _ in range(max(1, round(TEAR_BAND / edge_length))):  # grow the band by one ring of edges
        reached = torch.zeros(len(weights)).index_add_(0, edges[:, 0], tear[edges[:, 1]].float())
        reached.index_add_(0, edges[:, 1], tear[edges[:, 0]].float())
        tear |= reached > 0
    return tear


class LbsMethod:
    """Per-frame garment positions by linear blend skinning (no dynamics)."""

    name = "lbs"

    def __init__(self, garment: Garment, body: Body, **_):
        self.rest_vertices = garment.vertices
        self.weights = garment_skin_weights(garment, body)

    def run(self, posed: PosedBody) -> torch.Tensor:
        """A posed body (T frames) -> (T,V,3) garment positions."""
        return linear_blend_skinning(self.rest_vertices, self.weights, posed.skinning_transforms)

    def frames(self, posed: PosedBody) -> Iterator[torch.Tensor]:
        """Yield each frame's (V,3) garment positions, one frame at a time (for benchmarks)."""
        for t in range(posed.skinning_transforms.shape[0]):
            yield linear_blend_skinning(self.rest_vertices, self.weights, posed.skinning_transforms[t : t + 1])[0]
