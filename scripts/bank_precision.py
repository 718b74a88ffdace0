"""Teacher rollouts for the rollout bank four ways on the same draws: float32 and bfloat16 autocast,
eager and compiled (docs/experiments/2026-11-30-bfloat16-bank.md).

    python scripts/bank_precision.py DRAWS fp32,fp32c,bf16,bf16c [SEED]

Prints one JSON line per draw and variant: seconds of the rollout (TeacherMethod.run only), eps_e,
eps_a, eps_c (%), drift rise/gap (mm), detached %, and against the first variant the RMS, largest
and last-frame vertex distance (mm).
"""
import json
import sys
import time

import torch

from hyperbones.geometry.proximity import BodyProximity
from hyperbones.models.loading import teacher_from_checkpoint
from hyperbones.models.teacher import Autocast
from hyperbones.physics.metrics import area_error_pct, collision_pct, edge_error_pct
from hyperbones.runtime.teacher_method import TeacherMethod
from hyperbones.training.config import load_config
from hyperbones.training.data import TeacherData
from hyperbones.training.rollouts import (compiled_for_inference, detached_above_hips, drift,
                                          signed_distances_from_start)

torch.set_num_threads(1)

draws, variants = int(sys.argv[1]), sys.argv[2].split(",")
seed = int(sys.argv[3]) if len(sys.argv) > 3 else 777
config = load_config("configs/hyperbones-draped.toml")
base, _ = teacher_from_checkpoint(config.train.init_from)
base.eval()
models = {}
for variant in variants:
    network = Autocast(base) if variant.startswith("bf16") else base
    models[variant] = compiled_for_inference(network) if variant.endswith("c") else network
data = TeacherData(config.data, seed=seed)
search = None  # Warp's body search, made for the first body (every Anny body has the same faces)
with torch.no_grad():
    for draw in range(draws):
        identity = data.sample_identity()
        at_end = data.random.random() < config.joint.end_fraction
        window, root = data.sample_window(config.joint.rollout_frames, identity, at_end=at_end)
        posed = identity.body.pose(window.joint_rotations, root)
        garment = identity.garment
        reference = None
        for variant in variants:
            method = TeacherMethod(garment, identity.body, garment.vertices, garment.material, model=models[variant],
                                   settle_dt=config.data.settle_dt, device="cpu")
            start = time.perf_counter(); positions = method.run(posed); seconds = time.perf_counter() - start
            rise, gap = drift(positions, identity.skin(posed.skinning_transforms))
            search = search or BodyProximity(identity.body.faces)
            distances, start_distances = signed_distances_from_start(search, positions, posed.vertices,
                                                                     garment.vertices, identity.body.rest_vertices)
            # as RolloutCache.detachment, from the distances already measured
            detached = detached_above_hips(distances, start_distances, garment.vertices,
                                           float(identity.body.rest_joint_positions[0, 2]))
            row = dict(draw=draw, variant=variant, name=identity.name, V=positions.shape[1], T=positions.shape[0],
                       seconds=round(seconds, 2), eps_e=float(edge_error_pct(positions, identity.rest)),
                       eps_a=float(area_error_pct(positions, identity.rest)),
                       eps_c=float(collision_pct(distances)), rise_mm=rise * 1e3, gap_mm=gap * 1e3, detached=detached)
            if reference is None:
                reference = positions
            else:
                diff = (positions - reference).norm(dim=-1)
                row.update(rms_mm=float(diff.square().mean().sqrt()) * 1e3, max_mm=float(diff.max()) * 1e3,
                           last_rms_mm=float(diff[-1].square().mean().sqrt()) * 1e3)
            print(json.dumps(row), flush=True)
