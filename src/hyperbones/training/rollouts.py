"""A's targets in phase 2: whole rollouts of the teacher (Module C), kept and refreshed.

Each rollout is C run without gradient from the LBS start (after its settling step) over a
training clip on a random identity, as ``hyperbones simulate --method teacher`` runs it, so
A learns C's lag, swing and settling along a whole motion, not only a few steps from an LBS
pose. Every ``refresh_every`` steps the oldest rollout is replaced by one of the current C.

A rollout is kept only if, over its last third, the garment stays near its skinned pose
(``drift``: its mean height above it within ``max_rise``, its RMS distance within
``max_gap``); the teacher lets some garments creep up the body or slide off, and such a
rollout would teach A a wrong place for the garment. A refused one is replaced by a new
draw (up to ``MAX_DRAWS`` in all).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from hyperbones.models.teacher import Teacher
from hyperbones.runtime.identity import IdentityGeometry
from hyperbones.simulate.teacher import TeacherMethod
from hyperbones.training.config import JointConfig
from hyperbones.training.data import Identity as PhysicsIdentity
from hyperbones.training.data import TeacherData


@dataclass
class TeacherRollout:
    """C along one clip on one identity (T frames).

    physics: the identity's cloth (rest state, body, carried garment).
    geometry: its virtual bones, UV maps and canonical graph (what Module B reads).
    joint_rotations: (T,31,3,3); root_translation: (T,3); skinning: (T,31,4,4);
    body_vertices: (T,Vb,3); positions: (T,V,3) C's garment; edges: (E,2) the garment's
    edges; step: when it was made; latents: filled in by a trainer whose trunk is frozen.
    """

    physics: PhysicsIdentity
    geometry: IdentityGeometry
    joint_rotations: torch.Tensor
    root_translation: torch.Tensor
    skinning: torch.Tensor
    body_vertices: torch.Tensor
    positions: torch.Tensor
    edges: torch.Tensor
    motion: str
    step: int
    latents: torch.Tensor | None = None  # (V,latent) a frozen trunk's output on geometry.graph, once computed

    @property
    def num_frames(self) -> int:
        return self.positions.shape[0]


MAX_DRAWS = 5  # rollouts drawn per refresh before the last one is kept whatever its drift


def drift(positions: torch.Tensor, skinned: torch.Tensor) -> tuple[float, float]:
    """(T,V,3) C's garment and (T,V,3) the same garment skinned -> over the last third of
    the frames, the mean height of C's garment above the skinned one (m) and the mean RMS
    distance between them (m)."""
    tail = slice(positions.shape[0] - max(1, positions.shape[0] // 3), None)
    offset = positions[tail] - skinned[tail]
    return float(offset[..., 2].mean()), float(offset.square().sum(-1).mean(-1).sqrt().mean())


class RolloutCache:
    """Up to ``config.cache_size`` teacher rollouts; ``sample`` draws a (rollout, frame) pair."""

    def __init__(self, data: TeacherData, config: JointConfig, num_bones: int, uv_resolution: int,
                 device: torch.device, settle_dt: float):
        self.data, self.config = data, config
        self.num_bones, self.uv_resolution = num_bones, uv_resolution
        self.device, self.settle_dt = device, settle_dt
        self.rollouts: list[TeacherRollout] = []
        self.refused = 0  # rollouts not kept for their drift

    def make(self, teacher: Teacher, step: int) -> TeacherRollout:
        """A new rollout of ``teacher`` that passes the drift check (the last of ``MAX_DRAWS`` otherwise)."""
        for _ in range(MAX_DRAWS - 1):
            rollout, rise, gap = self._draw(teacher, step)
            if self.config.max_rise > 0 and rise > self.config.max_rise:
                self.refused += 1
            elif self.config.max_gap > 0 and gap > self.config.max_gap:
                self.refused += 1
            else:
                return rollout
        return self._draw(teacher, step)[0]

    def _draw(self, teacher: Teacher, step: int) -> tuple[TeacherRollout, float, float]:
        """One rollout of ``teacher`` (put in eval mode for it: its input statistics stay as
        they are) and its ``drift``."""
        data = self.data
        identity = data.sample_identity()
        at_end = data.random.random() < self.config.end_fraction
        window, root = data.sample_window(self.config.rollout_frames, identity, at_end=at_end)
        posed = identity.body.pose(window.joint_rotations, root)
        garment = identity.garment
        was_training = teacher.training
        teacher.eval()
        try:
            method = TeacherMethod(garment, identity.body, garment.vertices, garment.material, model=teacher,
                                   settle_dt=self.settle_dt, device=str(self.device))
            positions = method.run(posed)
        finally:
            teacher.train(was_training)
        geometry = IdentityGeometry.build(garment, identity.body, self.num_bones, self.uv_resolution, self.device,
                                          name=identity.name)
        rise, gap = drift(positions, identity.skin(posed.skinning_transforms))
        return (TeacherRollout(identity, geometry, window.joint_rotations, root, posed.skinning_transforms,
                               posed.vertices, positions, garment.edges(), window.name, step), rise, gap)

    def refresh(self, teacher: Teacher, step: int) -> TeacherRollout:
        """Add a rollout, dropping the oldest when the cache is full."""
        rollout = self.make(teacher, step)
        if len(self.rollouts) >= self.config.cache_size:
            oldest = min(range(len(self.rollouts)), key=lambda i: self.rollouts[i].step)
            self.rollouts.pop(oldest)
        self.rollouts.append(rollout)
        return rollout

    def sample(self) -> tuple[TeacherRollout, int]:
        """A cached rollout and a frame t >= 2 of it (A's window needs t−2 and t−1)."""
        rollout = self.data.random.choice(self.rollouts)
        return rollout, self.data.random.randrange(2, rollout.num_frames)
