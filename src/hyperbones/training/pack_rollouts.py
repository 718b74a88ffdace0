"""Phase 2's teacher rollouts made from a pack, many at once: ``RolloutCache``'s job in torch alone.

A batch of identities (random pack bodies, templates, fabrics, clip windows of one length)
is rolled out by C as one concatenated garment (``training.episode_batch``), with the same
start, settling step, strain limiting and contact as ``runtime.teacher_rollout.StepRollout``,
so a GPU makes hundreds of rollouts in the time one takes; the drift and detachment checks
of ``training.rollouts`` keep or refuse each. Each kept rollout gets its identity's geometry
(virtual bones, UV maps, canonical graph) from the pack: the bones' picks and geodesic
distances come from the template on the default body (geodesics need potpourri3d), their
skinning weights from the skin under them on the rollout's body.
"""

from __future__ import annotations

import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.batched_proximity import BatchedProximity
from hyperbones.geometry.surface import push_outside
from hyperbones.geometry.torch_proximity import TorchProximity
from hyperbones.geometry.uv_raster import UvRaster
from hyperbones.models.cloth_graph import FRAME_DT, canonical_graph
from hyperbones.models.teacher import Autocast, teacher_step
from hyperbones.physics.energies import COLLISION_EPSILON
from hyperbones.physics.hard_contact import QUERY_DISTANCE, constrain_step
from hyperbones.rig.virtual_bones import VirtualBones, bone_joint_weights, initial_log_weights
from hyperbones.runtime.identity import IdentityGeometry
from hyperbones.training.config import JointConfig
from hyperbones.training.episode import Identity
from hyperbones.training.episode_batch import EpisodeBatch
from hyperbones.training.pack_data import PackData
from hyperbones.training.rollouts import (
    RolloutCache, TeacherRollout, detached_above_hips, drift, refused, signed_distances_from_start,
)


@torch.no_grad()
def roll_out(teacher, batch: EpisodeBatch, bodies: torch.Tensor, skinned: torch.Tensor,
             proximity: BatchedProximity, settle_dt: float) -> torch.Tensor:
    """C along T frames of a batch: bodies (T,B·Vb,3), skinned (T,N,3) the garments by LBS
    -> (T,N,3). Frame 0 settles on the still first pose; frame t > 0 is the step t−1 -> t."""
    movable = ~batch.topology.pinned_mask
    proximity.update(bodies[0])
    positions = push_outside(skinned[0], proximity.query(skinned[0], max_distance=QUERY_DISTANCE),
                             COLLISION_EPSILON, movable=movable)
    velocities = torch.zeros_like(positions)
    frames = []
    for t in range(bodies.shape[0]):
        now, following = (0, 0) if t == 0 else (t - 1, t)
        nearest = proximity.query(positions, max_distance=QUERY_DISTANCE)  # the search holds bodies[now]
        positions, velocities = teacher_step(teacher, batch.topology, batch.rest, positions, velocities,
                                             skinned[following], bodies[now], bodies[following], batch.body_faces,
                                             nearest, settle_dt if t == 0 else FRAME_DT)
        positions, velocities = constrain_step(positions, velocities, batch.limiter, proximity, nearest,
                                               bodies[following], movable, COLLISION_EPSILON, QUERY_DISTANCE,
                                               vertex_garment=batch.episode_of_vertex)
        if t == 0:
            velocities = torch.zeros_like(velocities)  # the first pose is held still before it
        frames.append(positions)
    return torch.stack(frames)


class PackGeometry:
    """Identity geometry (``IdentityGeometry``) of pack identities, torch only; UV rasters
    (which depend on the template alone) are made once per template and resolution."""

    def __init__(self, data: PackData, num_bones: int, uv_resolution: int, device: torch.device):
        """Raises a ``ParameterError`` naming the pack unless its templates have ``num_bones`` bones."""
        self.data, self.num_bones, self.uv_resolution, self.device = data, num_bones, uv_resolution, device
        if data.pack.num_bones != num_bones:
            raise ParameterError(f"{data.pack.path}: {data.pack.num_bones} virtual bones per template, the config "
                                 f"asks for {num_bones} (make the pack with this phase-2 config)")
        self.rasters: dict = {}
        self.search = TorchProximity(data.pack.body_faces, device=device)

    def build(self, identity: Identity) -> IdentityGeometry:
        """The geometry of ``identity`` (its carried garment at rest on its canonical body), on the device."""
        device = self.device
        template = self.data.sources[(identity.name, identity.resolution)]
        garment, body = identity.garment, identity.body
        faces, canonical_body = body.faces.to(device), body.rest_vertices.to(device)
        vertices, picked = garment.vertices.to(device), template.bone_vertex.to(device)
        self.search.update(canonical_body)
        under_bones = self.search.query(identity.rest.rest_vertices.to(device)[picked], max_distance=10.0)
        bones = VirtualBones(vertices[picked].clone(), picked,
                             bone_joint_weights(under_bones, faces, body.skin_weights.to(device)),
                             initial_log_weights(template.bone_distance.to(device), vertices, picked))
        key = (identity.name, identity.resolution)
        if key not in self.rasters:
            self.rasters[key] = UvRaster.build(garment.faces, garment.uvs, garment.face_uvs, garment.num_vertices,
                                               self.uv_resolution).to(device)
        graph = canonical_graph(identity.topology.to(device), canonical_body, faces,
                                self.search.query(vertices, max_distance=1.0))
        return IdentityGeometry(identity.name, vertices, garment.faces.to(device), body.rest_joint_positions.to(device),
                                bones, self.rasters[key], graph, garment.uvs.to(device), garment.face_uvs.to(device))


class PackRollouts(RolloutCache):
    """Up to ``config.cache_size`` rollouts of C (``RolloutCache``'s cache and draws), simulated
    ``batch`` at a time on ``device`` from a pack instead of one by one on Anny bodies."""

    def __init__(self, data: PackData, config: JointConfig, num_bones: int, uv_resolution: int,
                 device: torch.device, settle_dt: float, batch: int, bfloat16: bool = False):
        super().__init__(data, config, num_bones, uv_resolution, device, settle_dt)
        self.batch, self.bfloat16 = max(1, int(batch)), bfloat16  # bfloat16: C's network in autocast
        self.geometry = PackGeometry(data, num_bones, uv_resolution, device)
        self.waiting: list[TeacherRollout] = []  # simulated, not yet in the cache
        self.simulated = 0

    def simulate(self, teacher, step: int) -> list[TeacherRollout]:
        """One batch of rollouts of ``teacher`` (in eval mode for it); those that pass the drift
        and detachment checks (all of them when none does, as ``RolloutCache`` keeps its last draw)."""
        data = self.data
        identities = [data.sample_identity() for _ in range(self.batch)]
        windows = []
        for identity in identities:
            at_end = data.random.random() < self.config.end_fraction
            windows.append((at_end, *data.sample_window(self.config.rollout_frames, identity, at_end=at_end)))
        frames = min(window.num_frames for _, window, _ in windows)
        cut = [(window.slice(window.num_frames - frames, window.num_frames) if at_end else window.slice(0, frames),
                root[-frames:] if at_end else root[:frames]) for at_end, window, root in windows]
        posed = [data.pose(identity, window.joint_rotations, root) for identity, (window, root) in zip(identities, cut)]
        skinned = [garment for _, _, garment in posed]
        batch = EpisodeBatch.of(identities, data.pack.body_faces).to(self.device)
        proximity = batch.proximity(self.device)
        bodies = torch.stack([vertices for vertices, _, _ in posed], 1).flatten(1, 2)  # (T,B·Vb,3)
        was_training = teacher.training
        teacher.eval()
        try:
            network = Autocast(teacher) if self.bfloat16 else teacher
            positions = roll_out(network, batch, bodies, torch.cat(skinned, 1), proximity, self.settle_dt)
        finally:
            teacher.train(was_training)
        self.simulated += len(identities)
        detached = self.batch_detachment(identities, batch, proximity, positions, bodies)
        made, kept = [], []
        for index, (identity, ours) in enumerate(zip(identities, torch.split(positions, batch.sizes, dim=1))):
            rise, gap = drift(ours, skinned[index])
            window, root = cut[index]
            vertices, transforms, _ = posed[index]
            rollout = TeacherRollout(identity, self.geometry.build(identity), window.joint_rotations.to(self.device),
                                     root.to(self.device), transforms, vertices, ours,
                                     identity.garment.edges().to(self.device), window.name, step)
            made.append(rollout)
            if not refused(self.config, rise, gap, detached[index]):
                kept.append(rollout)
        self.refused += len(made) - len(kept)
        return kept or made

    def batch_detachment(self, identities: list[Identity], batch: EpisodeBatch, proximity: BatchedProximity,
                         positions: torch.Tensor, bodies: torch.Tensor) -> list[float]:
        """Each rollout's share of vertex-frames come off above the hips (``detached_above_hips``)
        from the batch's garments (T,N,3) on their bodies (T,B·Vb,3), against where each started
        on its canonical body; zeros without the check."""
        if self.config.max_detached_pct <= 0:
            return [0.0] * len(identities)
        starts = [identity.garment.vertices.to(self.device) for identity in identities]
        canonical = torch.cat([identity.body.rest_vertices for identity in identities]).to(self.device)
        distances, reference = signed_distances_from_start(proximity, positions, bodies, torch.cat(starts), canonical)
        return [detached_above_hips(ours, theirs, start, float(identity.body.rest_joint_positions[0, 2]))
                for ours, theirs, start, identity in zip(distances.split(batch.sizes, 1), reference.split(batch.sizes),
                                                         starts, identities)]

    def refresh(self, teacher, step: int) -> TeacherRollout:
        """Add a rollout (simulating a new batch when none is waiting), dropping the oldest when full."""
        if not self.waiting:
            self.waiting = self.simulate(teacher, step)
        rollout = self.waiting.pop()
        rollout.step = step
        return self.admit(rollout)


__all__ = ["PackGeometry", "PackRollouts", "roll_out"]
