"""Phase 2 of ``hyperbones train`` (paper Sec. 3.5): Modules A, B and C trained together.

Every optimiser step sums
  - C's physics terms on its own episode (exactly the teacher trainer's step), and
  - A's terms on ``joint.frames_per_step`` frames drawn from a cache of C's whole rollouts
    (``training.rollouts``): Module B encodes the frame's identity (through the trunk C
    uses, so both losses train it), Module A predicts the garment from the bone window,
    and ``runtime_terms`` compares it with C's state there.
With ``joint.train_teacher`` off, C and the trunk are frozen (a finished phase-1 teacher):
a step is A's terms alone, and each rollout's trunk latents are computed once.
The rollout cache is rebuilt from the current C when a run resumes (it is not saved).
One process only (no DDP).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import torch

from hyperbones.errors import ParameterError
from hyperbones.models.hyperbones import HyperBonesConfig, HyperBonesModel
from hyperbones.models.loading import load_checkpoint
from hyperbones.models.module_a import heading_frame
from hyperbones.models.teacher import Teacher
from hyperbones.physics.hard_contact import QUERY_DISTANCE
from hyperbones.runtime.identity import apply_encoder
from hyperbones.runtime.simulator import IdentityBatch, module_a_frame
from hyperbones.training.config import HyperBonesTrainingConfig
from hyperbones.training.loss import collision_weight_at, runtime_terms
from hyperbones.training.trainer import TeacherTrainer, check_sections

INITIAL_ROLLOUTS = 4  # made before the first step; the cache then grows by one per refresh


class JointTrainer(TeacherTrainer):
    """The teacher trainer's loop and checkpoints, with Modules A and B added to each step."""

    label = "hyperbones"

    def __init__(self, config: HyperBonesTrainingConfig, run_dir: str | Path, resume: bool = False,
                 progress: bool = True, max_steps: int | None = None):
        if int(os.environ.get("WORLD_SIZE", "1")) > 1:
            raise ParameterError("joint (HyperBones) training runs on one process; start it without torchrun")
        if not config.joint.train_teacher and config.joint.trunk_from_runtime:
            raise ParameterError("joint.trunk_from_runtime needs joint.train_teacher: "
                                 "a frozen trunk cannot learn from A")
        super().__init__(config, run_dir, resume=resume, progress=progress, max_steps=max_steps)
        if not config.joint.train_teacher:
            self.teacher.requires_grad_(False)  # Adam skips parameters without gradients
            self.teacher.eval()  # its input statistics stay as phase 1 left them
        self.cache = self._make_rollouts()
        self.runtime_proximity = self._make_runtime_proximity()

    def _make_rollouts(self):
        """The cache of C's rollouts that A learns from: simulated on Anny bodies, or a bank's."""
        from hyperbones.training.rollouts import RolloutCache

        config = self.config
        return RolloutCache(self.data, config.joint, config.runtime.num_bones, config.runtime.uv_resolution,
                            self.device, config.data.settle_dt)

    def _make_runtime_proximity(self):
        """The body search for A's interpenetration and collision terms (Warp's)."""
        from hyperbones.geometry.proximity import BodyProximity

        return BodyProximity(self.data.default_body.faces, device=self.device)

    def _build_model(self) -> torch.nn.Module:
        return HyperBonesModel(HyperBonesConfig(self.config.model, self.config.runtime))

    def _initialise_from(self, path: Path) -> None:
        """A phase-1 teacher starts C and the trunk; a joint checkpoint (training or exported)
        starts the whole model, from its weights' moving average where it keeps one."""
        payload = load_checkpoint(path, map_location=self.device)
        if "runtime" not in payload["config"]:
            super()._initialise_from(path, payload)
            return
        check_sections(path, payload, self.config, ("model", "runtime"))
        self.model.load_state_dict(payload.get("ema") or payload["model"])

    @property
    def teacher(self) -> Teacher:
        return self.model.teacher

    def shown_terms(self) -> dict[str, str]:
        if self.config.joint.train_teacher:
            return super().shown_terms()
        return {"loss": "loss", "a_mse": "a_mse", "a_strain": "a_stretching"}

    def _teacher_terms(self) -> tuple[dict[str, torch.Tensor], dict[str, float]]:
        terms, logs = super()._teacher_terms() if self.config.joint.train_teacher else ({}, {})
        logs["refused_rollouts"] = float(self.cache.refused)
        return terms, logs

    def _extra_terms(self) -> dict[str, torch.Tensor]:
        joint = self.config.joint
        if not self.cache.rollouts:
            if self.progress:
                print("preparing teacher rollouts for Module A", flush=True)
            started = time.perf_counter()
            # Loaded from a bank they are cheap: fill the whole cache at once.
            for _ in range(joint.cache_size if joint.bank else min(INITIAL_ROLLOUTS, joint.cache_size)):
                self.cache.refresh(self.teacher, self.step)
            if self.progress:
                print(f"{len(self.cache.rollouts)} rollouts ready in {time.perf_counter() - started:.0f} s", flush=True)
        elif self.step % joint.refresh_every == 0:
            self.cache.refresh(self.teacher, self.step)  # grows until full, then replaces the oldest
        weight = collision_weight_at(self.step, self.config.train.collision_weight_start,
                                     self.config.train.collision_weight_end, self.config.train.collision_ramp_steps)
        totals: dict[str, torch.Tensor] = {}
        for _ in range(joint.frames_per_step):
            for name, value in self._runtime_frame_terms(weight).items():
                totals[name] = totals.get(name, 0.0) + value / joint.frames_per_step
        return totals

    def _runtime_frame_terms(self, collision_weight: float) -> dict[str, torch.Tensor]:
        """Module B then A on one cached frame, against C's garment there."""
        rollout, t = self.cache.sample()
        device = self.device
        if not self.config.joint.train_teacher and rollout.latents is None:
            with torch.no_grad():
                rollout.latents = self.model.trunk_latents(rollout.geometry.graph, train_trunk=False)
        identity = apply_encoder(self.model, rollout.geometry, train_trunk=self.config.joint.trunk_from_runtime,
                                 latents=rollout.latents)
        # A's window: frames t−K+1 … t; before the rollout's first frame it repeats that
        # frame, as the runtime does when it starts.
        frames = (torch.arange(t - self.config.runtime.window_frames + 1, t + 1)).clamp_min(0)
        rotations, positions = identity.bones.pose(rollout.skinning[frames].to(device))  # (K,B,3,3), (K,B,3)
        to_local = heading_frame(rollout.joint_rotations[t, 0].to(device), rollout.root_translation[t].to(device))
        garment = module_a_frame(self.model.runtime, IdentityBatch.of([identity]), positions[None], rotations[-1:],
                                 positions[-1:], to_local[None])[0]
        body = rollout.body_vertices[t].to(device)
        self.runtime_proximity.update(body)
        nearest = self.runtime_proximity.query(garment.detach(), max_distance=QUERY_DISTANCE)
        return runtime_terms(garment, rollout.positions[t].to(device), rollout.edges.to(device),
                             rollout.physics.rest.to(device), nearest, body, self.body_faces, collision_weight,
                             self.config.joint)
