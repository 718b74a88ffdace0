"""The torch-only trainer: phase 1 (the teacher) or phase 2 (Modules A and B) from a training pack.

    python -m hyperbones.training.from_pack --pack PACK --config CONFIG --out DIR [--resume] [--minutes M]

It imports torch, numpy, scipy, tensorboard and roma (pure Python), not Anny, Warp or
potpourri3d: bodies, garments and motions come from the pack (``hyperbones pack``), the body
search is ``TorchProximity``. So it runs on the project's GPU machines, which have none of
those, and anywhere else. The loop, losses, curriculum and moving average are
``hyperbones train``'s (``TeacherTrainer``, ``JointTrainer``); what differs:
  - a step advances ``--batch`` episodes at once, as one concatenated garment on their
    bodies side by side (``training.episode_batch``), and its loss is their mean;
  - phase 2's teacher rollouts are simulated ``--rollout-batch`` at a time (``training.pack_rollouts``);
  - the state is a compact one (``training.compact_state``: shards under 15 MiB, Adam's
    moments in bfloat16), saved every ``--checkpoint-minutes`` and when ``--minutes`` run out.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import torch

from hyperbones.training.compact_state import has_compact_state, load_compact_state, save_compact_state
from hyperbones.training.episode_batch import EpisodeBatch
from hyperbones.training.joint import JointTrainer
from hyperbones.training.pack_data import PackData, TrainingPack
from hyperbones.training.trainer import EpisodeRun, TeacherTrainer, train_to_end


class PackTraining:
    """What a trainer changes to learn from a pack (mixed in before ``TeacherTrainer`` or ``JointTrainer``)."""

    def __init__(self, config, run_dir, pack: TrainingPack, batch: int = 1, rollout_batch: int = 8, **options):
        self.pack, self.batch, self.rollout_batch = pack, max(1, int(batch)), max(1, int(rollout_batch))
        self.episode_steps = 0  # episode-steps taken by this process (a step of a batch of B counts B)
        super().__init__(config, run_dir, **options)

    def _has_state(self) -> bool:
        return has_compact_state(self.run_dir)

    def _restore(self) -> None:
        model, ema, optimizer, step, saved = load_compact_state(self.run_dir, self.device)
        self._check_resumed_config(saved, self.run_dir / "index.pt")
        self.model.load_state_dict(model)
        self.optimizer.load_state_dict(optimizer)
        self.step, self.ema = step, ema

    def save(self) -> None:
        if not self.is_main:
            return
        self.writer.flush()
        save_compact_state(self.run_dir, self.model.state_dict(), self.ema, self.optimizer.state_dict(), self.step,
                           self.config.as_dict())

    def _prepare_data(self, seed: int) -> None:
        self.data = PackData(self.pack, self.config.data, seed=seed, device=self.device)
        self.body_faces = self.pack.body_faces.to(self.device)
        self.proximity = None  # each batch of episodes makes its own

    def _begin_episode(self, steps: int) -> EpisodeRun:
        episodes = [self.data.sample_episode(steps) for _ in range(self.batch)]
        batch = EpisodeBatch.of([episode.identity for episode in episodes], self.pack.body_faces).to(self.device)
        bodies = torch.stack([episode.body_vertices for episode in episodes], 1).flatten(1, 2)  # (K+2,B·Vb,3)
        lbs = torch.cat([episode.garment_lbs for episode in episodes], 1)  # (K+2,N,3)
        return EpisodeRun(batch.topology, batch.rest, batch.limiter, bodies, lbs, batch.body_faces,
                          batch.proximity(self.device), len(episodes), batch.episode_of_vertex)

    def _teacher_terms(self):
        terms, logs = super()._teacher_terms()
        if terms:
            self.episode_steps += self._episode.episodes if self._episode is not None else self.batch
        return terms, logs


class PackTeacherTrainer(PackTraining, TeacherTrainer):
    """Phase 1 from a pack."""


class PackJointTrainer(PackTraining, JointTrainer):
    """Phase 2 from a pack: the rollouts A learns from are simulated in batches on the device."""

    def _make_rollouts(self):
        from hyperbones.training.pack_rollouts import PackRollouts

        config = self.config
        return PackRollouts(self.data, config.joint, config.runtime.num_bones, config.runtime.uv_resolution,
                            self.device, config.data.settle_dt, self.rollout_batch, config.train.bfloat16)

    def _extra_terms(self):
        terms = super()._extra_terms()
        self.episode_steps += self.config.joint.frames_per_step
        return terms


def trainer_for(config, run_dir, pack: TrainingPack, **options):
    """The pack trainer of ``config``'s phase (a ``[joint]`` config: phase 2)."""
    from hyperbones.training.config import HyperBonesTrainingConfig

    kind = PackJointTrainer if isinstance(config, HyperBonesTrainingConfig) else PackTeacherTrainer
    return kind(config, run_dir, pack, **options)


def timed_steps(trainer, steps: int, warmup: int = 2) -> list[float]:
    """Seconds of each of ``steps`` optimiser steps of a pack trainer after ``warmup`` untimed
    ones (a first batch of episodes or a filled rollout cache, then a warm step), synchronised
    with the device at both ends of each: ``scripts/device/phase*_steps.py``'s measure."""
    sync = torch.cuda.synchronize if trainer.device.type == "cuda" else (lambda: None)
    seconds = []
    for index in range(warmup + steps):
        sync()
        start = time.perf_counter()
        trainer._advance()
        trainer.step += 1
        sync()
        if index >= warmup:
            seconds.append(time.perf_counter() - start)
    return seconds


QUICK_TRAINING = ("train.log_every=1", "train.rollout_start=2", "train.rollout_max=2", "train.rollout_ramp_steps=0")
"""``--quick``'s training settings (with ``training.pack.QUICK_DATA``); phase 2 adds ``QUICK_JOINT``."""
QUICK_JOINT = ("joint.rollout_frames=6", "joint.cache_size=2", "joint.refresh_every=2", "joint.frames_per_step=1",
               "joint.frames_per_rollout=1")
SMOKE_STEPS = 3  # ``--smoke``: steps past the first rollouts and the first refresh


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m hyperbones.training.from_pack",
        description="Train from a training pack (hyperbones pack) with torch alone: phase 1 for a teacher config, "
                    "phase 2 for a config with [joint]. The run folder holds a compact resumable state (index.pt "
                    "and shards under 15 MiB) and TensorBoard logs; it ends with a one-line JSON summary. Phase 1 "
                    "also runs under torchrun (DDP, a batch per process: on two CPU cores, two processes of one "
                    "thread each beat one of two).")
    parser.add_argument("--pack", required=True, help="training pack written by `hyperbones pack` for this config")
    parser.add_argument("--config", required=True, help="TOML training config (the one the pack was made for)")
    parser.add_argument("--out", required=True, help="run folder")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out")
    parser.add_argument("--minutes", type=float, default=None, help="stop (saving) after this many minutes")
    parser.add_argument("--checkpoint-minutes", type=float, default=1.0,
                        help="save the state at least this often (default 1), besides train.checkpoint_every")
    parser.add_argument("--batch", type=int, default=None,
                        help="episodes per optimiser step (default: 64 on CUDA, 4 on the CPU)")
    parser.add_argument("--rollout-batch", type=int, default=None,
                        help="phase 2: teacher rollouts simulated at once (default: 64 on CUDA, 4 on the CPU)")
    parser.add_argument("--device", default=None, help="auto, cpu or cuda[:N] (default: the config's train.device)")
    parser.add_argument("--max-steps", type=int, default=None, help="stop at this step (below train.steps)")
    parser.add_argument("--set", action="append", default=None, metavar="SECTION.KEY=VALUE",
                        help="override one config field (as hyperbones train --set)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--smoke", action="store_true",
                        help="a check that a step runs on this pack and device: short rollouts, batches of 2, "
                             f"{SMOKE_STEPS} steps (the GPU job runs it first, to fail in seconds, not minutes)")
    parser.add_argument("--quick", action="store_true",
                        help="a check that the whole job runs: --smoke's settings on a --quick pack's data, "
                             "15 seconds unless --minutes says otherwise")
    args = parser.parse_args(argv)

    from hyperbones.devices import pick_device
    from hyperbones.errors import HyperbonesError
    from hyperbones.training.config import HyperBonesTrainingConfig, apply_overrides, load_config
    from hyperbones.training.pack import QUICK_DATA

    try:
        short = args.quick or args.smoke
        overrides = [*(QUICK_DATA if args.quick else ()), *(QUICK_TRAINING if short else ()), *(args.set or ())]
        config = apply_overrides(load_config(args.config), overrides)
        if short and isinstance(config, HyperBonesTrainingConfig):
            config = apply_overrides(config, QUICK_JOINT)
        if short:
            args.batch, args.rollout_batch = 2, 2
        if args.quick:
            args.minutes = 0.25 if args.minutes is None else args.minutes
        if args.smoke:
            args.max_steps = SMOKE_STEPS
        if args.device:
            config = apply_overrides(config, [f"train.device={args.device}"])
        pack = TrainingPack(args.pack)
        cuda = pick_device(config.train.device).type == "cuda"
        batch = args.batch or (64 if cuda else 4)
        rollout_batch = args.rollout_batch or (64 if cuda else 4)
        trainer = trainer_for(config, args.out, pack, batch=batch, rollout_batch=rollout_batch, resume=args.resume,
                              progress=not args.quiet, max_steps=args.max_steps)
    except HyperbonesError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.minutes is not None:
        trainer.deadline = time.monotonic() + 60.0 * args.minutes
    trainer.checkpoint_seconds = 60.0 * args.checkpoint_minutes
    first, started = trainer.step, time.perf_counter()
    step = train_to_end(trainer)
    seconds = time.perf_counter() - started
    if trainer.is_main:  # every process steps its own batches of the same size, in lockstep
        processes = int(os.environ.get("WORLD_SIZE", "1"))
        print(json.dumps({"step": step, "steps_this_run": step - first, "seconds": round(seconds, 1),
                          "episode_steps_per_second": round(processes * trainer.episode_steps / max(seconds, 1e-9), 2),
                          "batch": batch, "processes": processes, "device": str(trainer.device),
                          "state": str(Path(args.out).resolve())}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
