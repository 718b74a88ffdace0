"""Phase 2 of ``hyperbones train`` (paper Sec. 3.5): Modules A, B and C trained together.

Every optimiser step sums
  - C's physics terms on its own episode (exactly the teacher trainer's step), and
  - A's terms on ``joint.frames_per_step`` frames drawn from a cache of C's whole rollouts
    (``training.rollouts``; ``joint.frames_per_rollout`` of each drawn rollout), in one
    batch: Module B encodes each rollout's identity (through the trunk C uses, so both
    losses train it), Module A predicts the garments from their bone windows, and
    ``runtime_terms`` compares them with C's states there.
With ``joint.train_teacher`` off, C and the trunk are frozen (a finished phase-1 teacher):
a step is A's terms alone, and each rollout's trunk latents are computed once.
The rollout cache is rebuilt from the current C when a run resumes (it is not saved).
One process only (no DDP).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.batched_proximity import BatchedProximity
from hyperbones.models.hyperbones import HyperBonesConfig, HyperBonesModel
from hyperbones.models.loading import load_checkpoint
from hyperbones.models.module_a import heading_frame
from hyperbones.models.teacher import Teacher
from hyperbones.physics.hard_contact import QUERY_DISTANCE
from hyperbones.runtime.identity import apply_encoder
from hyperbones.runtime.simulator import IdentityBatch, grouped_rows, module_a_frame
from hyperbones.training.config import HyperBonesTrainingConfig
from hyperbones.training.episode_batch import joined_rest
from hyperbones.training.loss import collision_weight_at, runtime_terms
from hyperbones.training.trainer import TeacherTrainer, check_sections

if TYPE_CHECKING:  # training.rollouts reaches Anny's body: imported where the Anny cache is made
    from hyperbones.training.rollouts import TeacherRollout

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

    def _make_rollouts(self):
        """The cache of C's rollouts that A learns from: simulated on Anny bodies, or a bank's."""
        from hyperbones.training.rollouts import RolloutCache

        config = self.config
        return RolloutCache(self.data, config.joint, config.runtime.num_bones, config.runtime.uv_resolution,
                            self.device, config.data.settle_dt)

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
        return self._runtime_frames_terms(self.cache.sample_frames(joint.frames_per_step, joint.frames_per_rollout),
                                          weight)

    def _runtime_frames_terms(self, samples: list[tuple[TeacherRollout, int]],
                              collision_weight: float) -> dict[str, torch.Tensor]:
        """Module B then A on F cached frames at once (a rollout and a frame t of it each),
        against C's garments there: ``runtime_terms``' mean over the F frames. Module B runs once
        per distinct rollout, and A's per-identity work once per identity (``module_a_frame``).

        The F garments go through Module A as one batch, are searched on their F bodies in one
        query (``BatchedProximity``: Warp's search per body on a CPU that has it, the torch
        search over all bodies at once elsewhere) and are scored as one joined mesh, so a
        step of many frames keeps a GPU busy.
        """
        device, window = self.device, self.config.runtime.window_frames
        identities, windows, rotations, to_local, targets, bodies, rests, edge_lists = [], [], [], [], [], [], [], []
        for rollout, rows in grouped_rows([rollout for rollout, _ in samples]):
            times = torch.tensor([samples[row][1] for row in rows])  # (n,) the frames of this rollout
            if not self.config.joint.train_teacher and rollout.latents is None:
                with torch.no_grad():
                    rollout.latents = self.model.trunk_latents(rollout.geometry.graph, train_trunk=False)
            identity = apply_encoder(self.model, rollout.geometry, train_trunk=self.config.joint.trunk_from_runtime,
                                     latents=rollout.latents)
            identities += [identity] * len(rows)
            rests += [rollout.physics.rest.to(device)] * len(rows)
            edge_lists += [rollout.edges.to(device)] * len(rows)
            # A's window: frames t−K+1 … t; before the rollout's first frame it repeats that
            # frame, as the runtime does when it starts.
            frames = (times[:, None] + torch.arange(1 - window, 1)).clamp_min(0)  # (n,K)
            frame_rotations, frame_positions = identity.bones.pose(rollout.skinning[frames].to(device))
            windows.append(frame_positions)  # (n,K,B,3)
            rotations.append(frame_rotations[:, -1])  # (n,B,3,3)
            to_local.append(heading_frame(rollout.joint_rotations[times, 0].to(device),
                                          rollout.root_translation[times].to(device)))  # (n,4,4)
            targets.append(rollout.positions[times].to(device).flatten(0, 1))  # (n·V,3) C's garments
            bodies.append(rollout.body_vertices[times].to(device))  # (n,Vb,3)
        windows = torch.cat(windows)  # (F,K,B,3)
        garments = module_a_frame(self.model.runtime, IdentityBatch.of(identities), windows, torch.cat(rotations),
                                  windows[:, -1], torch.cat(to_local))
        rest, offsets = joined_rest(rests)
        positions = torch.cat(garments)  # (N,3), the F garments in the order of ``identities``
        edges = torch.cat([frame_edges + offset for frame_edges, offset in zip(edge_lists, offsets.tolist())])
        bodies = torch.cat(bodies)  # (F,Vb,3)
        proximity = BatchedProximity(self.body_faces, bodies.shape[1], offsets, device)
        proximity.update(bodies)
        nearest = proximity.query(positions.detach(), max_distance=QUERY_DISTANCE)
        return runtime_terms(positions, torch.cat(targets), edges, rest, nearest, bodies.reshape(-1, 3),
                             proximity.faces, collision_weight, self.config.joint,
                             frame_sizes=[len(garment) for garment in garments])
