"""``hyperbones bench-runtime``: the per-frame runtime alone, on saved identity caches (Module A
and the follow in the heading frame; no body, so no contact or edge projection).

Needs only Module A, identity caches (``Identity.save``) and a motion ``.npz`` (``hyperbones
motion NAME --out FILE``): no body model, teacher or Warp, so it runs wherever torch does
(a deployment target, a GPU machine). Each identity is stepped through the motion, ``batch``
copies at once (one ``Simulator`` over ``batch`` characters); the first ``warmup`` frames
are not timed, then the median and 95th percentile of the per-frame times are reported (CUDA
synchronised).
Without a checkpoint, Module A's weights are freshly initialised: the timing is the same.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.jobs.timing import BenchRecord, timed_blocks
from hyperbones.models.loading import load_module_a
from hyperbones.models.module_a import ModuleA, ModuleAConfig
from hyperbones.runtime.config import RuntimeConfig
from hyperbones.runtime.identity import Identity
from hyperbones.runtime.simulator import Simulator


def load_motion_npz(path: str | Path) -> tuple[torch.Tensor, torch.Tensor]:
    """(T,31,3,3) rotations from the A-pose and (T,3) root positions of a ``hyperbones motion`` .npz."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(path, "motion file not found")
    try:
        with np.load(path) as data:
            rotations = torch.from_numpy(data["joint_rotations_from_apose"]).float()
            roots = torch.from_numpy(data["root_translation"]).float()
    except (OSError, ValueError, KeyError) as error:
        raise InputFileError(path, f"not a hyperbones motion .npz ({type(error).__name__}: {error})") from None
    return rotations, roots


def bench_runtime(identity_paths: list[str], motion: str, *, checkpoint: str | None = None,
                  uv_resolution: int | None = None, device: str = "cpu", batch: int = 1, frames: int = 60,
                  warmup: int = 10, late: int | None = None, runtime: str | None = None) -> list[BenchRecord]:
    """One record per identity cache: the median and 95th percentile ms per frame (for the
    whole batch) of ``Simulator.step``; with ``late``, a second record for the frames from
    ``late`` on (past the motion's end the pose is held). ``runtime``: ``--runtime`` settings
    over the defaults (no body here, so only the follow's matter)."""
    if batch < 1 or frames < 1 or warmup < 0:
        raise ParameterError("--batch and --frames must be >= 1, --warmup >= 0")
    the_device = torch.device(device)
    if the_device.type == "cuda" and not torch.cuda.is_available():
        raise ParameterError("--device cuda asked for, but CUDA is not available")
    config = RuntimeConfig().with_overrides(runtime)
    rotations, roots = load_motion_npz(motion)
    trained = load_module_a(checkpoint) if checkpoint else None
    records = []
    for path in identity_paths:
        identity = Identity.load(path)
        resolution = uv_resolution or identity.raster.resolution
        identity = identity.at_resolution(resolution)
        if trained is not None:
            module_a = trained
        else:
            torch.manual_seed(0)
            layers, _, hidden = identity.film.shape  # the Bone-Net the cache was made for
            module_a = ModuleA(ModuleAConfig(num_bones=identity.bones.num_bones, hidden=hidden, layers=layers,
                                             uv_features=identity.vertex_features.shape[1],
                                             uv_resolution=resolution))
        simulator = Simulator(module_a, [identity] * batch, the_device, config=config)

        def step(t: int) -> None:
            t = min(t, rotations.shape[0] - 1)  # past the motion's end: held at its last pose
            simulator.step(rotations[t].expand(batch, 31, 3, 3).to(the_device),
                           roots[t].expand(batch, 3).to(the_device))

        for block in timed_blocks(step, the_device, warmup, frames, late):
            records.append(BenchRecord(f"hyperbones@{resolution}", identity.name, identity.num_vertices,
                                       the_device.type, batch, block.median, block.p95, block.first))
    return records

