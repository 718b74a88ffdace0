"""Phase 1's optimiser step (the teacher) at several batch sizes: milliseconds a step and episode-steps per second.

    PYTHONPATH=src:.device/train/site python3 scripts/device/phase1_steps.py PACK DEVICE B [B ...] \
        [--config CONFIG] [--quick]

B: episodes a step (``from_pack --batch``), one concatenated garment on their bodies side by
side. Episodes run their full length from the first step (``train.rollout_ramp_steps`` 0),
as in a run's steady state. One trainer per size; ``STEPS`` ($PHASE1_STEPS, 10) timed steps after
two warm-up ones, synchronised at both ends; a step that starts a new batch of episodes is
timed too, so the median is a step inside an episode. CONFIG: configs/teacher.toml (the paper's
size, what the GPU job trains) by default. Against the CPU's rate on the same pack, this is
the GPU's share of #27's 100x target; the call that measures both phases on the GPU machine:
scripts/device/throughput.sh.
"""

import argparse
import os
import statistics
import tempfile

import torch

from hyperbones.training.config import apply_overrides, load_config
from hyperbones.training.from_pack import timed_steps, trainer_for
from hyperbones.training.pack_data import TrainingPack

STEPS = int(os.environ.get("PHASE1_STEPS", "10"))


def step_seconds(pack: TrainingPack, device: torch.device, config_path: str, batch: int,
                 data: tuple[str, ...] = ()) -> list[float]:
    """Seconds of each of STEPS teacher steps of ``batch`` episodes at once; data: overrides of the
    config's data (the small pack's, ``--quick``)."""
    config = apply_overrides(load_config(config_path), [*data, "train.rollout_ramp_steps=0", f"train.device={device}"])
    with tempfile.TemporaryDirectory() as out:
        trainer = trainer_for(config, out, pack, batch=batch, progress=False)
        seconds = timed_steps(trainer, STEPS)
        trainer.close()
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pack")
    parser.add_argument("device")
    parser.add_argument("batches", nargs="+", type=int)
    parser.add_argument("--config", default="configs/teacher.toml")
    parser.add_argument("--quick", action="store_true",
                        help="a pack made with --prepare --quick (a check on this machine)")
    args = parser.parse_args()
    data = ()
    if args.quick:
        from hyperbones.training.pack import QUICK_DATA  # reaches Anny: here, not on the GPU machine

        data = QUICK_DATA
    pack, device = TrainingPack(args.pack), torch.device(args.device)
    print(f"phase 1, {args.config}, {device}, {torch.get_num_threads()} threads")
    print("| episodes a step | ms a step (median) | episode-steps/s |\n|---:|---:|---:|")
    for batch in args.batches:
        try:
            median = statistics.median(step_seconds(pack, device, args.config, batch, data))
        except torch.OutOfMemoryError:  # the larger sizes cannot fit either
            print(f"| {batch} | out of memory | – |", flush=True)
            break
        print(f"| {batch} | {1000 * median:.1f} | {batch / median:.1f} |", flush=True)


if __name__ == "__main__":
    main()
