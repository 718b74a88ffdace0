"""``hyperbones train``: self-supervised training of the teacher (Module C) with L_phys.

Each optimiser step advances one episode by one simulation step, with the state detached
between steps (HOOD): an episode starts from the LBS-posed garment plus noise (cloth that
LBS put inside the body pushed out to the collision margin), takes one
long settling step with the body held still, then follows the motion for a rollout whose
length grows from ``rollout_start`` to ``rollout_max`` steps over training. The loss is
taken on each raw prediction; the state carried to the next step then gets the same strain
limiting and hard contact as the runtime (``physics.hard_contact.constrain_step``), so
training sees the states inference does.

Runs on one process, or on several under ``torchrun`` (DistributedDataParallel: gloo on
CPU, NCCL on CUDA with one GPU per process, gloo when processes share GPUs); each rank
samples its own episodes, rank 0 logs and checkpoints. One garment graph is too small to
fill a GPU, so several processes may share one (``torchrun --nproc_per_node 8`` on one
GPU: eight episodes per optimiser step).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.distributed as dist
from tqdm import tqdm

from hyperbones.devices import pick_device
from hyperbones.errors import ParameterError
from hyperbones.geometry.surface import push_outside
from hyperbones.models.cloth_graph import GarmentTopology
from hyperbones.models.loading import load_checkpoint, teacher_state
from hyperbones.models.teacher import Autocast, Teacher, teacher_step
from hyperbones.physics.energies import COLLISION_EPSILON
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.hard_contact import QUERY_DISTANCE, constrain_step
from hyperbones.physics.strain_limit import StrainLimiter
from hyperbones.training.checkpoint import load_optimizer_state, save_training_state
from hyperbones.training.config import TeacherTrainingConfig
from hyperbones.training.loss import collision_weight_at, physics_terms


@dataclass
class EpisodeRun:
    """What the steps of the current episode (or batch of episodes, as one garment) read.

    topology, rest, limiter: the garment's (concatenated over a batch); body_vertices:
    (K+2,Vb,3) the body along the window (a batch's bodies side by side); garment_lbs:
    (K+2,V,3) the garment skinned along it; body_faces: (Fb,3); proximity: the body's
    search (``BodyProximity`` or its torch twin), holding the body of the step to come;
    episodes: how many the run holds (the loss is their mean); vertex_garment: (V,) the
    episode of each vertex in a batch (its contact rounds stop on their own), else None.
    """

    topology: GarmentTopology
    rest: ClothRest
    limiter: StrainLimiter
    body_vertices: torch.Tensor
    garment_lbs: torch.Tensor
    body_faces: torch.Tensor
    proximity: object
    episodes: int = 1
    vertex_garment: torch.Tensor | None = None

    @property
    def num_steps(self) -> int:
        return self.body_vertices.shape[0] - 2


def learning_rate_at(step: int, config) -> float:
    """``config.learning_rate`` halved once for each of ``learning_rate_halve_at`` reached."""
    return config.learning_rate * 0.5 ** sum(step >= milestone for milestone in config.learning_rate_halve_at)


def rollout_length(step: int, config) -> int:
    if config.rollout_ramp_steps <= 0:
        return config.rollout_max
    fraction = min(1.0, step / config.rollout_ramp_steps)
    return int(round(config.rollout_start + fraction * (config.rollout_max - config.rollout_start)))


class TeacherTrainer:
    """Owns the model, optimiser, data, logs and checkpoints of one run directory."""

    label = "teacher"  # the progress bar's name of what trains

    def __init__(self, config: TeacherTrainingConfig, run_dir: str | Path, resume: bool = False,
                 progress: bool = True, max_steps: int | None = None):
        self.config = config
        self.run_dir = Path(run_dir)
        self.distributed = int(os.environ.get("WORLD_SIZE", "1")) > 1
        self.device = pick_device(config.train.device)
        if self.distributed and not dist.is_initialized():
            dist.init_process_group(self._join_device())
        self.rank = dist.get_rank() if self.distributed else 0
        self.is_main = self.rank == 0
        self.progress = progress and self.is_main
        self.max_steps = max_steps
        torch.manual_seed(config.train.seed + self.rank)

        self.model = self._build_model().to(self.device)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=config.train.learning_rate)
        self.step = 0
        self.ema: dict[str, torch.Tensor] | None = None  # the weights' moving average (train.ema_decay)
        self.checkpoint_path = self.run_dir / "checkpoint.pt"
        episode_seed = config.train.seed * 1000 + self.rank
        self.deadline: float | None = None  # time.monotonic() at which train() stops early (saving first)
        self.checkpoint_seconds: float | None = None  # also save this often (s), besides every checkpoint_every steps
        if resume and self._has_state():
            self._restore()
            episode_seed += 7919 * self.step
        elif self._has_state() and not resume:
            raise ParameterError(f"{self.run_dir} already holds a run: pass --resume to continue it or use another --out")
        elif config.train.init_from:
            self._initialise_from(Path(config.train.init_from))
        if self.ema is None:
            self.ema = {name: value.detach().clone() for name, value in self.model.state_dict().items()}
        # What each simulation step calls: Module C, wrapped for DDP when training on several ranks.
        self.ddp = (torch.nn.parallel.DistributedDataParallel(self.model) if self.distributed else self.teacher)
        if config.train.bfloat16:
            self.ddp = Autocast(self.ddp)
        self._prepare_data(episode_seed)
        self.writer = None
        if self.is_main:
            from torch.utils.tensorboard import SummaryWriter

            self.run_dir.mkdir(parents=True, exist_ok=True)
            # A resumed run drops what a killed one logged past its checkpoint (TensorBoard purges
            # the steps from purge_step on); the checkpoint's own step stays.
            self.writer = SummaryWriter(str(self.run_dir / "tensorboard"),
                                        purge_step=self.step + 1 if self.step else None)
        self._episode: EpisodeRun | None = None
        self._k = 0
        self._state = None

    def _has_state(self) -> bool:
        """Whether the run folder holds a state to resume."""
        return self.checkpoint_path.exists()

    def _restore(self) -> None:
        """Model, optimiser, step and moving average from the run folder's checkpoint."""
        payload = load_checkpoint(self.checkpoint_path, map_location=self.device)
        self._check_resumed_config(payload["config"], self.checkpoint_path)
        self.model.load_state_dict(payload["model"])
        self.optimizer.load_state_dict(load_optimizer_state(self.checkpoint_path, payload, self.device))
        self.step = int(payload["step"])
        self.ema = payload.get("ema")

    def _check_resumed_config(self, saved: dict, where) -> None:
        config = self.config
        if type(config).from_dict(saved, str(where)).as_dict() != config.as_dict():
            raise ParameterError(f"{where}: --resume with a different config than the run's")

    def _prepare_data(self, seed: int) -> None:
        """Set ``data`` (what episodes are drawn from), ``proximity`` (the body's search) and
        ``body_faces``: ``TeacherData`` on Anny bodies, with Warp's search."""
        from hyperbones.geometry.proximity import BodyProximity
        from hyperbones.training.data import TeacherData

        self.data = TeacherData(self.config.data, seed=seed,
                                progress=(lambda text: print(f"preparing {text}", flush=True)) if self.progress else None)
        self.proximity = BodyProximity(self.data.default_body.faces, device=self.device)
        self.body_faces = self.data.default_body.faces.to(self.device)

    def _begin_episode(self, steps: int) -> EpisodeRun:
        """A new episode of ``steps`` dynamic steps (one, here; the pack trainer's: a batch)."""
        episode = self.data.sample_episode(steps)
        identity = episode.identity
        return EpisodeRun(identity.topology.to(self.device), identity.rest.to(self.device),
                          identity.limiter.to(self.device), episode.body_vertices, episode.garment_lbs,
                          self.body_faces, self.proximity)

    def _build_model(self) -> torch.nn.Module:
        """The module the optimiser trains (here the teacher alone)."""
        return Teacher(self.config.model)

    @property
    def teacher(self) -> Teacher:
        """Module C inside the trained module."""
        return self.model

    def _join_device(self) -> str:
        """This rank's device and the process-group backend: NCCL with one GPU per process;
        gloo on CPU, and when there are more processes than GPUs (several ranks then share
        a GPU, each with its own episodes: NCCL allows one rank per GPU)."""
        if self.device.type != "cuda":
            return "gloo"
        local, world = int(os.environ.get("LOCAL_RANK", "0")), int(os.environ.get("WORLD_SIZE", "1"))
        gpus = torch.cuda.device_count()
        self.device = torch.device("cuda", local % gpus)
        torch.cuda.set_device(self.device)
        return "nccl" if world <= gpus else "gloo"

    def _initialise_from(self, path: Path, payload: dict | None = None) -> None:
        """Model weights and input statistics of another run's checkpoint (a fine-tuning start);
        ``payload``: that checkpoint, when already loaded."""
        payload = payload or load_checkpoint(path, map_location=self.device)
        check_sections(path, payload, self.config, ("model",))
        self.teacher.load_state_dict(teacher_state(payload, average=False))

    # -- one optimiser step -------------------------------------------------------------
    def _advance(self) -> dict[str, float]:
        """One optimiser step: the teacher's physics terms (plus ``_extra_terms``), summed."""
        terms, logs = self._teacher_terms()
        terms.update(self._extra_terms())
        loss = sum(terms.values())
        learning_rate = learning_rate_at(self.step, self.config.train)
        for group in self.optimizer.param_groups:
            group["lr"] = learning_rate
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.config.train.grad_clip)
        if torch.isfinite(grad_norm):
            self.optimizer.step()  # every rank sees the same averaged gradient, so all skip together
            self._update_average()
        logs.update({name: float(value.detach()) for name, value in terms.items()})
        logs.update(loss=float(loss.detach()), grad_norm=float(grad_norm), learning_rate=learning_rate)
        return logs

    def shown_terms(self) -> dict[str, str]:
        """The progress bar's label -> logged term."""
        return {"loss": "loss", "strain": "stretching", "coll": "collision"}

    def _extra_terms(self) -> dict[str, torch.Tensor]:
        """Loss terms added to the teacher's in the same step (none here; the joint trainer's A terms)."""
        return {}

    def _teacher_terms(self) -> tuple[dict[str, torch.Tensor], dict[str, float]]:
        """One simulation step of the current episode (a new episode when it has run out):
        L_phys's terms on the raw prediction, and the constrained, detached state carried on."""
        cfg = self.config
        if self._episode is None or self._k >= self._episode.num_steps:
            self._episode = run = self._begin_episode(rollout_length(self.step, cfg.train))
            lbs = run.garment_lbs[1].to(self.device)
            noise = torch.randn_like(lbs) * cfg.data.start_noise
            pinned = run.topology.pinned_mask
            start = torch.where(pinned[:, None], lbs, lbs + noise)
            # LBS pushes some cloth into the body; left there, the collision term's gradient
            # (w up to 5e5, cubic in the depth) drowns every other term of the loss.
            run.proximity.update(run.body_vertices[1].to(self.device))
            nearest = run.proximity.query(start, max_distance=QUERY_DISTANCE)
            start = push_outside(start, nearest, COLLISION_EPSILON, movable=~pinned)
            self._state = (start, torch.zeros_like(lbs))
            self._k = -1  # the settling step first
        run = self._episode
        if self._k < 0:
            frame_now = frame_next = 1
            dt = cfg.data.settle_dt
        else:
            frame_now, frame_next = self._k + 1, self._k + 2
            dt = 1.0 / 30.0
        body_now = run.body_vertices[frame_now].to(self.device)
        body_next = run.body_vertices[frame_next].to(self.device)
        pinned_next = run.garment_lbs[frame_next].to(self.device)
        positions, velocities = self._state
        # The search holds body_now already: posed at the episode's start, or by the last step's contact.
        nearest = run.proximity.query(positions, max_distance=QUERY_DISTANCE)
        positions_next, velocities_next = teacher_step(self.ddp, run.topology, run.rest, positions, velocities,
                                                       pinned_next, body_now, body_next, run.body_faces, nearest, dt)
        weight = collision_weight_at(self.step, cfg.train.collision_weight_start, cfg.train.collision_weight_end,
                                     cfg.train.collision_ramp_steps)
        terms = physics_terms(positions_next, positions, velocities, run.rest, nearest, body_now, body_next,
                              run.body_faces, weight, dt)
        if run.episodes > 1:  # a batch's loss is the mean of its episodes' (their energies add up)
            terms = {name: value / run.episodes for name, value in terms.items()}
        self._k += 1
        if torch.isfinite(positions_next).all():
            # The loss sees the raw prediction; the state carried on gets the runtime's strain
            # limiting and hard contact.
            positions_next, velocities_next = constrain_step(
                positions_next.detach(), velocities_next.detach(), run.limiter, run.proximity, nearest, body_next,
                ~run.topology.pinned_mask, COLLISION_EPSILON, QUERY_DISTANCE, vertex_garment=run.vertex_garment)
            if self._k == 0:
                # After settling, the garment moves with the body's LBS velocity at the first frame.
                velocities_next = (run.garment_lbs[1] - run.garment_lbs[0]).to(self.device)
            self._state = (positions_next, velocities_next)
        else:
            self._episode = None  # a blown-up episode is dropped; the loss still pushes against it
        logs = {"collision_weight": weight, "rollout": rollout_length(self.step, cfg.train),
                "settle": float(self._k == 0)}
        return terms, logs

    @torch.no_grad()
    def _update_average(self) -> None:
        """The weights' moving average (``train.ema_decay``); buffers (input statistics) and
        frozen parameters are copied."""
        decay = self.config.train.ema_decay
        parameters = {name for name, value in self.model.named_parameters() if value.requires_grad}
        state = self.model.state_dict()
        trained = [name for name in state if name in parameters]
        fixed = [name for name in state if name not in parameters]
        # One multi-tensor op each (not one per tensor): on a GPU every small op is a launch.
        torch._foreach_lerp_([self.ema[name] for name in trained], [state[name] for name in trained], 1.0 - decay)
        if fixed:
            torch._foreach_copy_([self.ema[name] for name in fixed], [state[name] for name in fixed])

    # -- the loop -----------------------------------------------------------------------
    def train(self) -> int:
        total = self.config.train.steps if self.max_steps is None else min(self.config.train.steps, self.max_steps)
        bar = tqdm(total=total, initial=self.step, desc=f"train {self.label}", disable=not self.progress, unit="step")
        started, first_step = time.perf_counter(), self.step
        saved_at = time.monotonic()
        running = {}
        try:
            while self.step < total and not (self.deadline and time.monotonic() >= self.deadline):
                logs = self._advance()
                self.step += 1
                for key, value in logs.items():
                    if math.isfinite(value):  # one blown-up episode must not blank the bar for good
                        running[key] = 0.9 * running.get(key, value) + 0.1 * value
                if self.is_main and self.step % self.config.train.log_every == 0:
                    for key, value in logs.items():
                        self.writer.add_scalar(f"train/{key}", value, self.step)
                    rate = (self.step - first_step) / max(time.perf_counter() - started, 1e-9)
                    self.writer.add_scalar("train/steps_per_second", rate, self.step)
                    bar.set_postfix({label: f"{running.get(key, math.nan):.3g}"
                                     for label, key in self.shown_terms().items()}, refresh=False)
                bar.update(1)
                timely = self.checkpoint_seconds and time.monotonic() - saved_at >= self.checkpoint_seconds
                if self.step % self.config.train.checkpoint_every == 0 or self.step == total or timely:
                    self.save()
                    saved_at = time.monotonic()
            if self.step < total and self.step > first_step:  # stopped by the deadline
                self.save()
        finally:
            bar.close()
            if self.writer:
                self.writer.flush()
        return self.step

    def save(self) -> None:
        if not self.is_main:
            return
        self.writer.flush()  # the log up to the checkpoint's step is on disk before the checkpoint is
        save_training_state(self.checkpoint_path, self.model.state_dict(), self.ema, self.optimizer.state_dict(),
                            self.step, self.config.as_dict())

    def close(self, finished: bool = True) -> None:
        """Flush the logs; after a ``finished`` run, leave the process group with the other
        ranks. A rank that failed leaves it alone: the others may be mid-collective, and its
        exit is what lets torchrun stop them."""
        if self.writer:
            self.writer.close()
        if finished and self.distributed and dist.is_initialized():
            # Every rank reaches here before any tears the group down: a rank that destroys it
            # while another still talks to it can leave that one waiting for good.
            dist.barrier()
            dist.destroy_process_group()


def train_to_end(trainer: TeacherTrainer) -> int:
    """Run ``trainer`` and close it (leaving its process group alone if it failed); its last step."""
    try:
        step = trainer.train()
    except BaseException:
        trainer.close(finished=False)
        raise
    trainer.close()
    return step


def check_sections(path, payload: dict, config: TeacherTrainingConfig, sections: tuple[str, ...]) -> None:
    """Raise unless the checkpoint ``payload`` (from ``path``, a train.init_from) has the
    same ``sections`` of the config as ``config``."""
    mine = config.as_dict()
    for section in sections:
        if payload["config"][section] != mine[section]:
            raise ParameterError(f"{path}: train.init_from has {section} {payload['config'][section]}, "
                                 f"this config {mine[section]}")


__all__ = ["EpisodeRun", "TeacherTrainer", "train_to_end", "learning_rate_at", "check_sections", "rollout_length"]
