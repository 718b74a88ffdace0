"""Phase 2's optimiser step at several batch sizes: milliseconds a step and episode-steps per second.

    PYTHONPATH=src:.device/train/site python3 scripts/device/phase2_steps.py PACK DEVICE F/G [F/G ...] [--quick]

F/G: ``joint.frames_per_step`` F, ``joint.frames_per_rollout`` G (8/1: eight frames of eight
rollouts; 64/8: eight frames from each of eight). One trainer per size on a cache of
``CACHE`` ($PHASE2_CACHE, 32) short rollouts (24 frames, made first and not timed, no refresh while timed);
``STEPS`` ($PHASE2_STEPS, 10) timed steps after two warm-up ones, synchronised at both ends. Picks the GPU
job's ``GPU_PHASE2`` (scripts/device/train.sh). On the GPU machine it runs in
scripts/device/throughput.sh's call, after phase 1's counterpart (phase1_steps.py).
Results: docs/experiments/2026-11-28-phase2-frames-in-batches.md.
"""

import argparse
import os
import statistics
import tempfile

import torch

from hyperbones.training.config import apply_overrides, load_config
from hyperbones.training.from_pack import timed_steps, trainer_for
from hyperbones.training.pack_data import TrainingPack

CACHE = int(os.environ.get("PHASE2_CACHE", "32"))  # rollouts in the cache (fewer for a check on a CPU)
STEPS = int(os.environ.get("PHASE2_STEPS", "10"))


def step_seconds(pack: TrainingPack, device: torch.device, frames: int, per_rollout: int,
                 data: tuple[str, ...] = ()) -> list[float]:
    """Seconds of each of STEPS phase-2 steps of ``frames`` frames, ``per_rollout`` from each rollout;
    data: overrides of the config's data (the small pack's, ``--quick``)."""
    config = apply_overrides(load_config("configs/hyperbones-small.toml"), [*data,
        f"joint.frames_per_step={frames}", f"joint.frames_per_rollout={per_rollout}", "joint.rollout_frames=24",
        f"joint.cache_size={CACHE}", "joint.refresh_every=1000000", f"train.device={device}"])
    with tempfile.TemporaryDirectory() as out:
        trainer = trainer_for(config, out, pack, batch=4, rollout_batch=CACHE, progress=False)
        seconds = timed_steps(trainer, STEPS)
        trainer.close()
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pack")
    parser.add_argument("device")
    parser.add_argument("sizes", nargs="+", help="F/G: frames a step / frames from each rollout")
    parser.add_argument("--quick", action="store_true",
                        help="a pack made with --prepare --quick (a check on this machine)")
    args = parser.parse_args()
    data = ()
    if args.quick:
        from hyperbones.training.pack import QUICK_DATA  # reaches Anny: here, not on the GPU machine

        data = QUICK_DATA
    pack, device = TrainingPack(args.pack), torch.device(args.device)
    print("| frames a step | frames a rollout | ms a step (median) | episode-steps/s |\n|---:|---:|---:|---:|")
    for size in args.sizes:
        frames, per_rollout = (int(value) for value in size.split("/"))
        try:
            median = statistics.median(step_seconds(pack, device, frames, per_rollout, data))
        except torch.OutOfMemoryError:  # the larger sizes cannot fit either
            print(f"| {frames} | {per_rollout} | out of memory | – |", flush=True)
            break
        print(f"| {frames} | {per_rollout} | {1000 * median:.1f} | {frames / median:.1f} |", flush=True)


if __name__ == "__main__":
    main()
