"""The autoregressive rollout that step-based methods (teacher, physics) share.

Frame 0 is the draped garment skinned to the first pose (any cloth inside the body pushed
out to the collision margin), relaxed by one long settling step with the body held still,
as every training episode starts; each later frame is one step t-1 -> t. Pinned vertices
follow the body by LBS. After every step, as in training, strain limiting keeps each edge
within a narrow band of its rest length while cloth that ended inside the body goes back
out on the side of the skin it came from (``physics.hard_contact.constrain_step``); the moves
are kept as velocity. A method supplies only ``_step``.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from tqdm import tqdm

from hyperbones.body.anny_body import Body, PosedBody
from hyperbones.garment.garment import Garment
from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.geometry.proximity import BodyProximity
from hyperbones.geometry.surface import Nearest, push_outside
from hyperbones.models.cloth_graph import FRAME_DT
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.energies import COLLISION_EPSILON
from hyperbones.physics.hard_contact import QUERY_DISTANCE
from hyperbones.physics.hard_contact import constrain_step
from hyperbones.physics.material import Material
from hyperbones.physics.strain_limit import StrainLimiter
from hyperbones.rig.garment_skinning import garment_skin_weights


class StepRollout:
    """Base of the step-based methods. A subclass sets ``name``, ``device`` and ``settle_dt``
    (s, the first step's length), calls ``_prepare_cloth`` and implements ``_step``."""

    name = "step"

    def _prepare_cloth(self, garment: Garment, body: Body, rest_vertices: torch.Tensor, material: Material,
                       progress: bool) -> ClothRest:
        """Set what every step-based rollout needs on ``self.device``: ``rest`` (``ClothRest``),
        ``movable`` (V,) bool, ``limiter``, ``canonical`` (V,3), ``skin_weights`` (V,J),
        ``body_faces`` and ``progress``. Returns the rest state on the CPU."""
        rest = ClothRest.from_mesh(rest_vertices.float(), garment.faces, material)
        self.rest = rest.to(self.device)
        pinned = torch.zeros(garment.num_vertices, dtype=torch.bool, device=self.device)
        pinned[garment.pinned.to(self.device)] = True
        self.movable = ~pinned
        self.limiter = StrainLimiter.for_cloth(self.rest, pinned)
        self.canonical = garment.vertices
        self.skin_weights = garment_skin_weights(garment, body)
        self.body_faces = body.faces.to(self.device)
        self.progress = progress
        return rest

    def _step(self, positions: torch.Tensor, velocities: torch.Tensor, pinned_next: torch.Tensor,
              body_now: torch.Tensor, body_next: torch.Tensor, nearest: Nearest, dt: float
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """One unconstrained step: state at t (V,3 each; velocity as per-step displacement),
        pinned vertices' next positions (V,3), body (Vb,3) at t and t+1, the body faces near
        ``positions`` -> x(t+1), v(t+1)."""
        raise NotImplementedError

    def run(self, posed: PosedBody) -> torch.Tensor:
        """(T frames of a posed body) -> (T,V,3) garment positions on the CPU."""
        frames = self.frames(posed)
        return torch.stack([frame.cpu() for frame in tqdm(frames, total=posed.vertices.shape[0], desc=self.name,
                                                         disable=not self.progress, unit="frame")])

    @torch.no_grad()
    def frames(self, posed: PosedBody) -> Iterator[torch.Tensor]:
        """Yield each frame's (V,3) garment positions (on the method's device) as it is computed."""
        skinned = linear_blend_skinning(self.canonical, self.skin_weights, posed.skinning_transforms)  # (T,V,3)
        body = posed.vertices
        proximity = BodyProximity(self.body_faces, device=self.device)
        proximity.update(body[0].to(self.device))
        start = skinned[0].to(self.device)
        positions = push_outside(start, proximity.query(start, max_distance=QUERY_DISTANCE), COLLISION_EPSILON,
                                 movable=self.movable)
        velocities = torch.zeros_like(positions)
        for t in range(body.shape[0]):
            # Frame 0: settle on the still body; frame t > 0: the step from t-1 to t.
            now, nxt = (0, 0) if t == 0 else (t - 1, t)
            body_now, body_next = body[now].to(self.device), body[nxt].to(self.device)
            nearest = proximity.query(positions, max_distance=QUERY_DISTANCE)  # the BVH holds body_now already
            positions, velocities = self._step(positions, velocities, skinned[nxt].to(self.device), body_now,
                                               body_next, nearest, self.settle_dt if t == 0 else FRAME_DT)
            positions, velocities = constrain_step(positions, velocities, self.limiter, proximity, nearest, body_next,
                                                   self.movable, COLLISION_EPSILON, QUERY_DISTANCE)
            if t == 0:
                velocities = torch.zeros_like(velocities)  # the first pose is held still before it
            yield positions
