"""``hyperbones bench``: milliseconds per frame (median and 95th percentile) of each method on
each garment, or of a crowd of characters stepped together.

Every method runs on the default body over a built-in walk; the first ``warmup`` frames
are not timed (caches, allocator, JIT), then each frame is timed on its own (CUDA work is
synchronised before the clock is read) and the median and 95th percentile are reported;
``late`` adds a second timed block that far into the motion, to show that the cost does not
grow with it. Posing the body is not part of a method's frame: it is shared by all methods
and done beforehand.

``profile`` charges each stage of the per-frame runtime (``runtime.stage_clock.STAGES``) to a
``StageClock`` over the first timed block, for the methods built on a ``Simulator``; the
record's ``stages`` holds the mean ms per frame of each.

``batch`` N > 1 times a crowd: N characters stepped together by one ``Simulator`` (the
hyperbones methods only), cycling through the garments and ``CROWD_BODIES``, each body
walking its own retargeted walk; the record holds ms per character-frame (frame time / N).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

import torch
from tqdm import tqdm

from hyperbones.body.anny_body import Body, body_for
from hyperbones.body.shape import BodyShape
from hyperbones.devices import pick_device
from hyperbones.errors import ParameterError
from hyperbones.garment.draped import draped_garment
from hyperbones.jobs.methods import METHODS
from hyperbones.jobs.timing import BenchRecord, timed_blocks
from hyperbones.motion.load import load_motion
from hyperbones.runtime.config import RAW, parse_overrides
from hyperbones.runtime.stage_clock import NO_CLOCK, StageClock

if TYPE_CHECKING:
    from hyperbones.runtime.simulator import Simulator

CROWD_BODIES = ("default",
                "gender=0.3,age=0.6,muscle=0.7,weight=0.3,height=0.6,proportions=0.4",
                "gender=0.8,age=0.4,muscle=0.3,weight=0.8,height=0.3,proportions=0.6",
                "gender=0.2,age=0.3,muscle=0.4,weight=0.2,height=0.8,proportions=0.5")
"""Body shapes a crowd (``batch`` > 1) cycles through: the default body, the two held-out
evaluation bodies (``training.config.EVAL_BODIES``, whose drapes ``eval`` may have cached) and
a tall slim one. Few on purpose: every body × garment is draped once (minutes on a fresh
machine, then cached on disk)."""

CROWD_METHODS = {"hyperbones": {}, "hyperbones-raw": RAW}
"""The methods a crowd can run (one ``Simulator`` steps every character), with the runtime
settings each puts over ``--runtime`` (as ``HyperBonesMethod`` does)."""


def crowd_characters(garments: list[str], count: int, bodies: int) -> list[tuple[str, int]]:
    """(garment, body index) of each of ``count`` characters over ``bodies`` body shapes (those
    of ``CROWD_BODIES``): the garments cycle fastest, then the bodies, so the first
    ``len(garments) × bodies`` characters are all different pairs (and only that many are
    draped and encoded, however large the crowd)."""
    return [(garments[i % len(garments)], (i // len(garments)) % bodies) for i in range(count)]


def _time_blocks(step: Callable[[int], None], device: torch.device, warmup: int, frames: int, late: int | None,
                 simulator: Simulator | None, batch: int, record: dict, prepare: Callable[[int], None] | None = None
                 ) -> list[BenchRecord]:
    """Time ``step`` (``timed_blocks``) and make one record per block from the fields in
    ``record``, in ms per character-frame (times / ``batch``). With a ``simulator``, its stages
    over the first block are charged to a ``StageClock`` and stored in that block's record."""
    clock = StageClock(device) if simulator is not None else None

    @contextmanager
    def first_block_profiled(index: int) -> Iterator[None]:
        if index == 0:
            simulator.profile(clock)
        try:
            yield
        finally:
            simulator.profile(NO_CLOCK)

    blocks = timed_blocks(step, device, warmup, frames, late, prepare=prepare,
                          around=first_block_profiled if clock is not None else None)
    return [BenchRecord(**record, device=device.type, batch=batch, ms_per_frame=block.median / batch,
                        p95_ms=block.p95 / batch, from_frame=block.first,
                        stages={name: ms / batch for name, ms in clock.per_frame().items()}
                        if clock is not None and index == 0 else {})
            for index, block in enumerate(blocks)]


def _walk(body: Body, length: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``body``'s walk over at most ``length`` frames, posed: (T,31,3,3) rotations, (T,3) Hips
    positions, (T,Vb,3) vertices (T ≤ ``length``: past the walk's end its last pose holds)."""
    motion = load_motion("walk", body)
    motion = motion.slice(0, min(length, motion.num_frames))
    posed = body.pose(motion.joint_rotations, motion.root_translation)
    return posed.joint_rotations, posed.joint_positions[:, 0], posed.vertices


def _bench_crowd(garments: list[str], count: int, methods: list[str], *, vertices: int | None,
                 device: torch.device, frames: int, warmup: int, late: int | None, checkpoint: str | None,
                 uv_resolution: int | None, overrides: dict, profile: bool, progress: bool) -> list[BenchRecord]:
    """Each method on a crowd of ``count`` characters (``crowd_characters``) stepped together by
    one ``Simulator``: each distinct garment × body is draped and encoded by Module B once, and
    characters sharing one share its identity."""
    from hyperbones.runtime.simulator import Simulator

    characters = crowd_characters(garments, count, len(CROWD_BODIES))
    used = sorted({body for _, body in characters})
    bodies = {index: body_for(BodyShape.parse(CROWD_BODIES[index])) for index in used}
    pairs = list(dict.fromkeys(characters))  # the distinct (garment, body) pairs, in crowd order
    slot = {pair: index for index, pair in enumerate(pairs)}
    draped = {(name, index): draped_garment(name, bodies[index], vertices=vertices)
              for name, index in tqdm(pairs, desc="crowd drapes", disable=not progress)}
    # Every body's walk, posed once; frame t of character i is row ``which[i]`` of frame t.
    walks = [_walk(bodies[index], (late if late is not None else warmup) + frames) for index in used]
    motion_frames = min(walk[0].shape[0] for walk in walks)
    rotations, roots, body_vertices = (torch.stack([walk[part][:motion_frames] for walk in walks], dim=1)
                                       for part in range(3))  # (T,B,31,3,3), (T,B,3), (T,B,Vb,3)
    which = torch.tensor([used.index(body) for _, body in characters])
    inputs: dict[str, torch.Tensor] = {"bodies": torch.empty(count, *body_vertices.shape[2:])}

    def gather(t: int) -> None:
        """Frame t's (N,31,3,3) rotations, (N,3) roots and (N,Vb,3) posed bodies (off the clock)."""
        t = min(t, motion_frames - 1)  # past the walk's end: held at its last pose
        inputs["rotations"], inputs["roots"] = rotations[t, which], roots[t, which]
        torch.index_select(body_vertices[t], 0, which, out=inputs["bodies"])

    vertex_count = round(sum(draped[pair][0].num_vertices for pair in characters) / count)
    name = f"crowd of {count} ({','.join(garments)} on {len(used)} {'body' if len(used) == 1 else 'bodies'})"
    records = []
    for method in tqdm(methods, desc="bench", disable=not progress):
        encoded = Simulator.load([(draped[pair][0], bodies[pair[1]]) for pair in pairs], checkpoint, device,
                                 uv_resolution, overrides={**overrides, **CROWD_METHODS[method]},
                                 rest_vertices=[draped[pair][1] for pair in pairs])
        identities = [encoded.identities[slot[pair]] for pair in characters]  # shared, not copied
        simulator = Simulator(encoded.module_a, identities, device, body_faces=bodies[used[0]].faces,
                              config=encoded.config)
        with_bodies = simulator.contact is not None

        def step(t: int) -> None:
            simulator.step(inputs["rotations"], inputs["roots"], inputs["bodies"] if with_bodies else None)

        records += _time_blocks(step, device, warmup, frames, late, simulator if profile else None, count,
                                {"method": method, "garment": name, "vertices": vertex_count}, prepare=gather)
    return records


def bench(methods: list[str], garments: list[str], *, vertices: int | None = None, device: str = "auto",
          frames: int = 30, warmup: int = 5, late: int | None = None, checkpoint: str | None = None,
          uv_resolution: int | None = None, progress: bool = True, runtime: str | None = None,
          batch: int = 1, profile: bool = False) -> list[BenchRecord]:
    """Time ``frames`` frames after ``warmup`` for each method × garment; one record each, and
    a second one for the ``frames`` frames from frame ``late`` on when given (the walk is then
    held still at its last pose for as long as it takes to get there).

    uv_resolution: the UV maps' R for the hyperbones method (default: its training one);
    runtime: ``--runtime`` settings for the hyperbones methods;
    batch: characters stepped together; above 1, one crowd record per method (hyperbones
    methods only) instead of one record per garment, in ms per character-frame;
    profile: the per-frame runtime's stages over the first timed block, in each record's
    ``stages`` (methods without the runtime, lbs and teacher, leave it empty).
    """
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ParameterError(f"unknown method(s) {unknown}; available: {', '.join(METHODS)}")
    if frames < 1 or warmup < 0:
        raise ParameterError("--frames must be >= 1 and --warmup >= 0")
    if batch < 1:
        raise ParameterError(f"--batch must be >= 1, got {batch}")
    if not garments:
        raise ParameterError("--garments names no garment")
    alone = [m for m in methods if m not in CROWD_METHODS]
    if batch > 1 and alone:
        raise ParameterError(f"--batch {batch} steps characters together in one Simulator, which only "
                             f"{' and '.join(CROWD_METHODS)} have; drop {', '.join(alone)} or use --batch 1")
    overrides = parse_overrides(runtime)
    the_device = pick_device(device)
    length = (late if late is not None else warmup) + frames
    if batch > 1:
        return _bench_crowd(garments, batch, methods, vertices=vertices, device=the_device, frames=frames,
                            warmup=warmup, late=late, checkpoint=checkpoint, uv_resolution=uv_resolution,
                            overrides=overrides, profile=profile, progress=progress)
    body = body_for(BodyShape())
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
            simulator = getattr(solver, "simulator", None) if profile else None
            records += _time_blocks(lambda t: next(stream), the_device, warmup, frames, late, simulator, 1,
                                    {"method": method, "garment": garment_name, "vertices": garment.num_vertices})
    return records
