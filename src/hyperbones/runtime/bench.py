"""``hyperbones bench``: median milliseconds per frame of each method on each garment.

Every method runs on the default body over a built-in walk; the first ``warmup`` frames
are not timed (caches, allocator, JIT), then each frame is timed on its own (CUDA work is
synchronised before the clock is read) and the median is reported. Posing the body is
not part of a method's frame: it is shared by all methods and done beforehand.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass

import torch
from tqdm import tqdm

from hyperbones.body.anny_body import body_for
from hyperbones.body.shape import BodyShape
from hyperbones.errors import ParameterError
from hyperbones.motion.load import load_motion
from hyperbones.simulate.garments import draped_garment
from hyperbones.simulate.pipeline import METHODS
from hyperbones.training.trainer import pick_device


@dataclass
class BenchRecord:
    method: str
    garment: str
    vertices: int
    device: str
    batch: int
    ms_per_frame: float


def bench(methods: list[str], garments: list[str], *, vertices: int | None = None, device: str = "auto",
          frames: int = 30, warmup: int = 5, checkpoint: str | None = None, uv_resolution: int | None = None,
          progress: bool = True) -> list[BenchRecord]:
    """Time ``frames`` frames after ``warmup`` for each method × garment; one record each.

    uv_resolution: the UV maps' R for the hyperbones method (default: its training one).
    """
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ParameterError(f"unknown method(s) {unknown}; available: {', '.join(METHODS)}")
    if frames < 1 or warmup < 0:
        raise ParameterError("--frames must be >= 1 and --warmup >= 0")
    the_device = pick_device(device)
    body = body_for(BodyShape())
    motion = load_motion("walk", body).slice(0, warmup + frames)
    posed = body.pose(motion.joint_rotations, motion.root_translation)
    records = []
    for garment_name in tqdm(garments, desc="bench", disable=not progress):
        garment, rest_vertices = draped_garment(garment_name, body, vertices=vertices)
        for method in methods:
            extra = {"uv_resolution": uv_resolution} if method == "hyperbones" else {}
            solver = METHODS[method](garment, body, rest_vertices=rest_vertices, material=garment.material,
                                     checkpoint=checkpoint, device=str(the_device), **extra)
            times = []
            stream = solver.frames(posed)
            for index in range(warmup + frames):
                _synchronize(the_device)
                start = time.perf_counter()
                next(stream)
                _synchronize(the_device)
                if index >= warmup:
                    times.append(1000.0 * (time.perf_counter() - start))
            records.append(BenchRecord(method, garment_name, garment.num_vertices, the_device.type, 1,
                                       statistics.median(times)))
    return records


def _synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def bench_table(records: list[BenchRecord]) -> str:
    lines = ["| method | garment | vertices | device | batch | ms/frame |", "|---|---|---:|---|---:|---:|"]
    lines += [f"| {r.method} | {r.garment} | {r.vertices} | {r.device} | {r.batch} | {r.ms_per_frame:.2f} |"
              for r in records]
    return "\n".join(lines)


def speedups(records: list[BenchRecord], fast: str = "hyperbones", slow: str = "teacher") -> list[str]:
    """One line per garment timed with both methods: how many times faster ``fast`` is."""
    timed = {(r.method, r.garment, r.vertices, r.device): r.ms_per_frame for r in records}
    return [f"{fast} is {timed[(slow, g, v, d)] / ms:.1f}x faster than the {slow} on {g} ({v} vertices, {d})"
            for (method, g, v, d), ms in timed.items() if method == fast and (slow, g, v, d) in timed]


def records_as_dicts(records: list[BenchRecord]) -> list[dict]:
    return [asdict(r) for r in records]
