"""``hyperbones bench``: median milliseconds per frame of each method on each garment.

Every method runs on the default body over a built-in walk; the first ``warmup`` frames
are not timed (caches, allocator, JIT), then each frame is timed on its own (CUDA work is
synchronised before the clock is read) and the median is reported; ``late`` adds a second
timed block that far into the motion, to show that the cost does not grow with it. Posing
the body is not part of a method's frame: it is shared by all methods and done beforehand.
"""

from __future__ import annotations

from tqdm import tqdm

from hyperbones.body.anny_body import body_for
from hyperbones.body.shape import BodyShape
from hyperbones.devices import pick_device
from hyperbones.errors import ParameterError
from hyperbones.garment.draped import draped_garment
from hyperbones.jobs.methods import METHODS
from hyperbones.jobs.timing import BenchRecord, timed_blocks
from hyperbones.motion.load import load_motion
from hyperbones.runtime.config import parse_overrides


def bench(methods: list[str], garments: list[str], *, vertices: int | None = None, device: str = "auto",
          frames: int = 30, warmup: int = 5, late: int | None = None, checkpoint: str | None = None,
          uv_resolution: int | None = None, progress: bool = True, runtime: str | None = None) -> list[BenchRecord]:
    """Time ``frames`` frames after ``warmup`` for each method × garment; one record each, and
    a second one for the ``frames`` frames from frame ``late`` on when given (the walk is then
    held still at its last pose for as long as it takes to get there).

    uv_resolution: the UV maps' R for the hyperbones method (default: its training one);
    runtime: ``--runtime`` settings for the hyperbones methods.
    """
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ParameterError(f"unknown method(s) {unknown}; available: {', '.join(METHODS)}")
    if frames < 1 or warmup < 0:
        raise ParameterError("--frames must be >= 1 and --warmup >= 0")
    overrides = parse_overrides(runtime)
    the_device = pick_device(device)
    body = body_for(BodyShape())
    length = (late if late is not None else warmup) + frames
    motion = load_motion("walk", body)
    motion = motion.with_hold(max(0, length - motion.num_frames)).slice(0, length)
    posed = body.pose(motion.joint_rotations, motion.root_translation)
    records = []
    for garment_name in tqdm(garments, desc="bench", disable=not progress):
        garment, rest_vertices = draped_garment(garment_name, body, vertices=vertices)
        for method in methods:
            extra = {"uv_resolution": uv_resolution, "runtime": overrides} if method.startswith("hyperbones") else {}
            solver = METHODS[method](garment, body, rest_vertices=rest_vertices, material=garment.material,
                                     checkpoint=checkpoint, device=str(the_device), **extra)
            stream = solver.frames(posed)
            for first, median in timed_blocks(lambda t: next(stream), the_device, warmup, frames, late):
                records.append(BenchRecord(method, garment_name, garment.num_vertices, the_device.type, 1, median,
                                           first))
    return records
