"""The teacher (Module C) as a simulation method: an autoregressive rollout over any length.

Frame 0 is the draped garment skinned to the first pose (any cloth inside the body pushed
out to the collision margin), relaxed by one long settling step with the body held still,
as every training episode starts; each later frame is one teacher step. Pinned vertices
follow the body by LBS. After every step, as in training, strain limiting keeps each edge
within a narrow band of its rest length while cloth that ended inside the body goes back
out on the side of the skin it came from (``physics.contact.constrain_step``); the moves
are kept as velocity.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import torch
from tqdm import tqdm

from hyperbones.body.anny_body import Body, PosedBody
from hyperbones.errors import ParameterError
from hyperbones.garment.garment import Garment
from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.geometry.proximity import BodyProximity, push_outside
from hyperbones.models.cloth_graph import FRAME_DT, GarmentTopology
from hyperbones.models.teacher import Teacher, teacher_step
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.contact import constrain_step
from hyperbones.physics.energies import COLLISION_EPSILON
from hyperbones.physics.material import Material
from hyperbones.physics.strain_limit import StrainLimiter
from hyperbones.simulate.lbs import garment_skin_weights
from hyperbones.training.checkpoint import SHIPPED_TEACHER
from hyperbones.training.config import DataConfig
from hyperbones.training.trainer import QUERY_DISTANCE, pick_device, teacher_from_checkpoint


class TeacherMethod:
    """Garment positions rolled out by a trained teacher checkpoint."""

    name = "teacher"

    def __init__(self, garment: Garment, body: Body, rest_vertices: torch.Tensor, material: Material | None = None,
                 checkpoint: str | Path | None = None, device: str = "auto", progress: bool = False,
                 model: Teacher | None = None, settle_dt: float | None = None):
        """``model`` (with ``settle_dt``, the length of the first step) rolls out a teacher in
        memory, e.g. the one being trained; otherwise ``checkpoint`` (default: the shipped one)."""
        self.device = pick_device(device)
        if model is not None:
            self.model, self.settle_dt = model, float(settle_dt if settle_dt is not None else DataConfig().settle_dt)
        else:
            if checkpoint is None and not SHIPPED_TEACHER.exists():
                raise ParameterError("no trained teacher ships with this version yet: train one with `hyperbones "
                                     "train` and pass --checkpoint FILE")
            self.model, payload = teacher_from_checkpoint(checkpoint or SHIPPED_TEACHER, self.device)
            self.settle_dt = float(payload["config"]["data"]["settle_dt"])
        material = material or garment.material
        rest = ClothRest.from_mesh(rest_vertices.float(), garment.faces, material)
        self.rest = rest.to(self.device)
        self.topology = GarmentTopology.build(rest.rest_vertices, garment.faces, garment.pinned, rest.vertex_masses,
                                              material).to(self.device)
        self.limiter = StrainLimiter.for_cloth(self.rest, self.topology.pinned_mask)
        self.movable = ~self.topology.pinned_mask
        self.canonical = garment.vertices
        self.skin_weights = garment_skin_weights(garment, body)
        self.body_faces = body.faces.to(self.device)
        self.progress = progress

    def run(self, posed: PosedBody) -> torch.Tensor:
        """(T frames of a posed body) -> (T,V,3) garment positions on the CPU."""
        frames = self.frames(posed)
        return torch.stack([frame.cpu() for frame in tqdm(frames, total=posed.vertices.shape[0], desc="teacher",
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
            positions, velocities = teacher_step(self.model, self.topology, self.rest, positions, velocities,
                                                 skinned[nxt].to(self.device), body_now, body_next, self.body_faces,
                                                 nearest, self.settle_dt if t == 0 else FRAME_DT)
            positions, velocities = constrain_step(positions, velocities, self.limiter, proximity, nearest, body_next,
                                                   self.movable, COLLISION_EPSILON, QUERY_DISTANCE)
            if t == 0:
                velocities = torch.zeros_like(velocities)  # the first pose is held still before it
            yield positions
