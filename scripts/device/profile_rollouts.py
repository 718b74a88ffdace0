"""Where phase 2's teacher rollouts spend their time (``PackRollouts.simulate``), part by part.

    PYTHONPATH=src:.device/train/site python3 scripts/device/profile_rollouts.py PACK DEVICE FRAMES BATCH... [--no-warp]

One warm-up batch, then one timed batch of each size, FRAMES frames long; each part is
timed with a device synchronisation around it (so the parts are not free to overlap).
--no-warp hides Warp, so the CPU takes the torch search the GPU machines take. On the GPU
machine: run(command="PYTHONPATH=src:.device/train/site python3 scripts/device/profile_rollouts.py
.device/train/hyperbones.pack.pt cuda 8 16 64", carry=[".device/train/site", ".device/train/hyperbones.pack.pt"]).
Results: docs/experiments/2026-11-28-first-gpu-training-call.md.
"""

import collections
import sys
import time

import torch

if "--no-warp" in sys.argv:
    sys.argv.remove("--no-warp")
    sys.modules["warp"] = None  # before anything imports it

import hyperbones.training.pack_rollouts as rollouts  # noqa: E402
from hyperbones.models.hyperbones import HyperBonesConfig, HyperBonesModel  # noqa: E402
from hyperbones.models.loading import load_checkpoint  # noqa: E402
from hyperbones.physics.strain_limit import StrainLimiter  # noqa: E402
from hyperbones.training.config import apply_overrides, load_config  # noqa: E402
from hyperbones.training.pack_data import PackData, TrainingPack  # noqa: E402

SPENT: dict[str, float] = collections.defaultdict(float)
CALLS: collections.Counter = collections.Counter()


def timed(name, function, sync):
    """``function`` with its time (synchronised on both sides) added to SPENT[name]."""
    def wrapper(*args, **kwargs):
        sync()
        start = time.perf_counter()
        out = function(*args, **kwargs)
        sync()
        SPENT[name] += time.perf_counter() - start
        CALLS[name] += 1
        return out
    return wrapper


def main() -> None:
    pack_path, device, frames = sys.argv[1], torch.device(sys.argv[2]), int(sys.argv[3])
    batches = [int(b) for b in sys.argv[4:]]
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    for owner, name, label in [(rollouts, "teacher_step", "teacher_step"), (rollouts, "constrain_step", "constrain_step"),
                               (rollouts, "roll_out", "roll_out"),
                               (rollouts.BatchedProximity, "query", "proximity.query (all)"),
                               (rollouts.BatchedProximity, "update", "proximity.update"),
                               (rollouts.PackGeometry, "build", "geometry.build"),
                               (rollouts.EpisodeBatch, "of", "EpisodeBatch.of"),
                               (PackData, "pose", "data.pose"), (PackData, "sample_identity", "data.sample_identity"),
                               (StrainLimiter, "project", "StrainLimiter.project")]:
        setattr(owner, name, timed(label, getattr(owner, name), sync))
    config = apply_overrides(load_config("configs/hyperbones-small.toml"), [f"joint.rollout_frames={frames}"])
    data = PackData(TrainingPack(pack_path), config.data, seed=0, device=device)
    payload = load_checkpoint("src/hyperbones/checkpoints/teacher.pt", map_location=device)
    model = HyperBonesModel(HyperBonesConfig(config.model, config.runtime)).to(device)
    state = payload.get("ema") or payload["model"]
    model.teacher.load_state_dict({key.removeprefix("teacher."): value for key, value in state.items()})
    for batch in batches:
        cache = rollouts.PackRollouts(data, config.joint, config.runtime.num_bones, config.runtime.uv_resolution,
                                      device, config.data.settle_dt, batch, config.train.bfloat16)
        cache.simulate(model.teacher, 0)  # warm-up
        SPENT.clear()
        CALLS.clear()
        sync()
        start = time.perf_counter()
        kept = cache.simulate(model.teacher, 0)
        sync()
        total = time.perf_counter() - start
        print(f"\n== {device} batch {batch} x {frames} frames: {total:.2f} s = {1000 * total / frames:.0f} ms a frame, "
              f"{1000 * total / (frames * batch):.1f} ms a rollout-frame (kept {len(kept)})")
        for name, seconds in sorted(SPENT.items(), key=lambda item: -item[1]):
            print(f"  {name:28s} {seconds:8.3f} s  {CALLS[name]:5d} calls  "
                  f"{1000 * seconds / max(CALLS[name], 1):8.2f} ms/call")


if __name__ == "__main__":
    main()
