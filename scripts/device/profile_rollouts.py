"""Where phase 2's teacher rollouts spend their time (``PackRollouts.simulate``), part by part.

    PYTHONPATH=src:.device/train/site python3 scripts/device/profile_rollouts.py PACK DEVICE FRAMES BATCH... [--no-warp]

One warm-up batch, then one timed batch of each size, FRAMES frames long; each part is
timed with a device synchronisation around it (so the parts are not free to overlap).
--no-warp hides Warp, so the CPU takes the torch search the GPU machines take. On the GPU
machine: run(command="PYTHONPATH=src:.device/train/site python3 scripts/device/profile_rollouts.py
.device/train/hyperbones.pack.pt cuda 8 16 64", carry=[".device/train/site", ".device/train/hyperbones.pack.pt"]).
Results: docs/experiments/2026-11-28-first-gpu-training-call.md.
"""
import sys, time, collections, torch
if "--no-warp" in sys.argv:
    sys.argv.remove("--no-warp"); sys.modules["warp"] = None
from hyperbones.training.config import load_config, apply_overrides
from hyperbones.training.pack_data import TrainingPack, PackData
import hyperbones.training.pack_rollouts as pr
import hyperbones.physics.hard_contact as hc
from hyperbones.models.loading import load_checkpoint
from hyperbones.models.hyperbones import HyperBonesModel, HyperBonesConfig
pack_path, device, frames = sys.argv[1], torch.device(sys.argv[2]), int(sys.argv[3])
batches = [int(b) for b in sys.argv[4:]]
sync = (lambda: torch.cuda.synchronize()) if device.type == "cuda" else (lambda: None)
spent = collections.defaultdict(float); calls = collections.Counter()
def timed(name, fn):
    def wrapper(*a, **k):
        sync(); t = time.perf_counter(); out = fn(*a, **k); sync()
        spent[name] += time.perf_counter() - t; calls[name] += 1; return out
    return wrapper
pr.teacher_step = timed("teacher_step", pr.teacher_step)
pr.constrain_step = timed("constrain_step", pr.constrain_step)
pr.push_outside = timed("push_outside", pr.push_outside)
pr.BatchedProximity.query = timed("proximity.query (all)", pr.BatchedProximity.query)
pr.BatchedProximity.update = timed("proximity.update", pr.BatchedProximity.update)
pr.PackGeometry.build = timed("geometry.build", pr.PackGeometry.build)
pr.EpisodeBatch.of = timed("EpisodeBatch.of", pr.EpisodeBatch.of)
pr.roll_out = timed("roll_out", pr.roll_out)
PackData.pose = timed("data.pose", PackData.pose)
PackData.sample_identity = timed("data.sample_identity", PackData.sample_identity)
import hyperbones.physics.strain_limit as sl
for cls in [getattr(sl, n) for n in dir(sl) if isinstance(getattr(sl, n), type)]:
    if hasattr(cls, "project") and cls.__module__ == sl.__name__:
        cls.project = timed(f"{cls.__name__}.project", cls.project)
config = apply_overrides(load_config("configs/hyperbones-small.toml"), [f"joint.rollout_frames={frames}"])
pack = TrainingPack(pack_path)
data = PackData(pack, config.data, seed=0, device=device)
payload = load_checkpoint("src/hyperbones/checkpoints/teacher.pt", map_location=device)
model = HyperBonesModel(HyperBonesConfig(config.model, config.runtime)).to(device)
state = payload.get("ema") or payload["model"]
model.teacher.load_state_dict({k.removeprefix("teacher."): v for k, v in state.items()})
for batch in batches:
    cache = pr.PackRollouts(data, config.joint, config.runtime.num_bones, config.runtime.uv_resolution, device,
                            config.data.settle_dt, batch, config.train.bfloat16)
    cache.simulate(model.teacher, 0)  # warm
    spent.clear(); calls.clear()
    sync(); t0 = time.perf_counter()
    kept = cache.simulate(model.teacher, 0)
    sync(); total = time.perf_counter() - t0
    vertices = sum(r.positions.shape[1] for r in kept)
    print(f"\n== {device} batch {batch} x {frames} frames: {total:.2f} s = {1000*total/frames:.0f} ms a frame, "
          f"{1000*total/(frames*batch):.1f} ms a rollout-frame (kept {len(kept)})")
    for name, seconds in sorted(spent.items(), key=lambda kv: -kv[1]):
        print(f"  {name:28s} {seconds:8.3f} s  {calls[name]:5d} calls  {1000*seconds/max(calls[name],1):8.2f} ms/call")
