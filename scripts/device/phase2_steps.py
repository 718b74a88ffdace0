"""Phase 2's optimiser step at several batch sizes: milliseconds a step and episode-steps per second.

    PYTHONPATH=src:.device/train/site python3 scripts/device/phase2_steps.py PACK DEVICE F/G [F/G ...]

F/G: ``joint.frames_per_step`` F, ``joint.frames_per_rollout`` G (8/1: eight frames of eight
rollouts; 64/8: eight frames from each of eight). One trainer per size on a cache of
``CACHE`` ($PHASE2_CACHE, 32) short rollouts (24 frames, made first and not timed, no refresh while timed);
``STEPS`` timed steps after two warm-up ones, synchronised at both ends. Picks the GPU
job's ``GPU_PHASE2`` (scripts/device/train.sh). On the GPU machine:
run(command="PYTHONPATH=src:.device/train/site python3 scripts/device/phase2_steps.py
.device/train/hyperbones.pack.pt cuda 4/1 64/8 256/8", carry=[".device/train/site", ".device/train/hyperbones.pack.pt"]).
Results: docs/experiments/2026-11-28-phase2-frames-in-batches.md.
"""

import os
import statistics
import sys
import tempfile
import time

import torch

from hyperbones.training.config import apply_overrides, load_config
from hyperbones.training.from_pack import trainer_for
from hyperbones.training.pack_data import TrainingPack

CACHE = int(os.environ.get("PHASE2_CACHE", "32"))  # rollouts in the cache (fewer for a check on a CPU)
STEPS = 10


def step_seconds(pack: TrainingPack, device: torch.device, frames: int, per_rollout: int) -> list[float]:
    """Seconds of each of STEPS phase-2 steps of ``frames`` frames, ``per_rollout`` from each rollout."""
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    config = apply_overrides(load_config("configs/hyperbones-small.toml"), [
        f"joint.frames_per_step={frames}", f"joint.frames_per_rollout={per_rollout}", "joint.rollout_frames=24",
        f"joint.cache_size={CACHE}", "joint.refresh_every=1000000", f"train.device={device}"])
    with tempfile.TemporaryDirectory() as out:
        trainer = trainer_for(config, out, pack, batch=4, rollout_batch=CACHE, progress=False)
        for _ in range(2):  # fills the cache, then a warm step
            trainer._advance()
            trainer.step += 1
        seconds = []
        for _ in range(STEPS):
            sync()
            start = time.perf_counter()
            trainer._advance()
            trainer.step += 1
            sync()
            seconds.append(time.perf_counter() - start)
        trainer.close()
    return seconds


def main() -> None:
    pack, device = TrainingPack(sys.argv[1]), torch.device(sys.argv[2])
    print("| frames a step | frames a rollout | ms a step (median) | episode-steps/s |\n|---:|---:|---:|---:|")
    for size in sys.argv[3:]:
        frames, per_rollout = (int(value) for value in size.split("/"))
        median = statistics.median(step_seconds(pack, device, frames, per_rollout))
        print(f"| {frames} | {per_rollout} | {1000 * median:.1f} | {frames / median:.1f} |", flush=True)


if __name__ == "__main__":
    main()
