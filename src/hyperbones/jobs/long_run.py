"""``hyperbones check long``: do the methods stay sound, fast and lean over a long motion?

Each method runs ``frames`` frames (default 10,000: 5.5 minutes at 30 fps) of a looping walk
and is reported in one table row: the fastest garment vertex, the count of non-finite vertex
positions, milliseconds per frame (median and 95th percentile) and the process's resident
memory at frame 100 and at the last frame, which should not grow beyond noise.

The frames are streamed (``method.frames``): no frame of the garment is kept. Posing the
body for every frame at once would cost frames x 13,718 vertices x 3 floats (1.6 GB for
10,000), so the body is posed once for one stretch of the walk and each later frame is a
posed frame of that stretch, moved by the distance walked (``LoopedWalk``).

The loop (``looped_walk``): the built-in walk, with its blend-in from the A-pose, runs to the
start of its steady gait; then one stretch of the steady gait is repeated, each repeat carried
forward by the distance it walks. The stretch is the one, a second or more long, whose end pose
best matches its start pose (a whole number of gait cycles, to the nearest frame). The
mismatch left (well under a frame's motion) is spread over the stretch: each joint's rotation
is turned back by a share of its end-to-start mismatch that grows from none at the stretch's
first frame to all of it at its end, the hips lowered likewise, so the last frame of one
repeat leads into the first of the next as smoothly as any two frames of the walk.
"""

from __future__ import annotations

import math
import resource
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import roma
import torch
from tqdm import tqdm

from hyperbones.body.anny_body import Body, PosedBody, body_for
from hyperbones.body.shape import BodyShape
from hyperbones.devices import pick_device
from hyperbones.errors import ParameterError
from hyperbones.garment.draped import draped_garment
from hyperbones.jobs.methods import METHODS
from hyperbones.jobs.timing import synchronize
from hyperbones.motion.load import load_motion

EARLY_FRAME = 100  # resident memory is read after this frame, and again after the last
MIN_STRETCH_SECONDS = 1.0  # the repeated stretch holds at least one gait cycle
STEADY_SPEED = 0.999  # a frame is in the steady gait when the hips move this share of the top speed


@dataclass
class LoopedWalk:
    """A walk that goes on for as many frames as asked: frames [0, start) once, then frames
    [start, start + length) over and over, each repeat moved on by ``advance``.

    table: the walk's frames [0, start + length), posed with vertices, the stretch smoothed;
    advance: (3,) m, how far one stretch walks (horizontal); join_mm: the largest joint
    position mismatch between the stretch's end and its start before smoothing; step_mm: the
    largest joint move from one frame to the next within the stretch, for scale.
    """

    table: PosedBody
    start: int
    length: int
    advance: torch.Tensor
    fps: float
    join_mm: float
    step_mm: float

    def repeats(self, frames: int) -> int:
        """How many times the stretch starts again within ``frames`` frames."""
        return max(0, math.ceil((frames - self.start) / self.length) - 1)

    def posed(self, frames: int) -> PosedBody:
        """The first ``frames`` frames, posed; the vertices are made frame by frame on demand."""
        t = torch.arange(frames)
        index = torch.where(t < self.start, t, self.start + (t - self.start) % self.length)
        shift = ((t - self.start).clamp_min(0) // self.length).float()[:, None] * self.advance  # (T,3)
        moved = {}
        for name in ("joint_world_transforms", "skinning_transforms"):
            transforms = getattr(self.table, name)[index]
            transforms[..., :3, 3] += shift[:, None]
            moved[name] = transforms
        return PosedBody(self.table.joint_positions[index] + shift[:, None], self.table.joint_rotations[index],
                         moved["joint_world_transforms"], moved["skinning_transforms"],
                         LoopedVertices(self.table.vertices, index, shift))

    def describe(self) -> str:
        distance = float(self.advance.norm())
        return (f"Looping walk: frames 0-{self.start - 1} once (the blend-in from the A-pose and the walk's start), "
                f"then frames {self.start}-{self.start + self.length - 1} ({self.length} frames, "
                f"{self.length / self.fps:.2f} s, {distance:.2f} m) repeated, each repeat carried {distance:.2f} m "
                f"further; their end-to-start mismatch, {self.join_mm:.1f} mm at the worst joint (the largest "
                f"joint move between two frames of the stretch: {self.step_mm:.0f} mm), is spread over the stretch.")


class LoopedVertices:
    """(T,Vb,3) body vertices of a ``LoopedWalk``, each frame made when it is indexed: one
    stretch's posed vertices ``table`` (C,Vb,3), which frame of it each frame is ``index``
    (T,) and how far that frame is moved ``shift`` (T,3). Indexing takes an int or a slice,
    as the methods' frame loops do."""

    def __init__(self, table: torch.Tensor, index: torch.Tensor, shift: torch.Tensor):
        self.table, self.index, self.shift = table, index, shift

    @property
    def shape(self) -> torch.Size:
        return torch.Size((len(self.index), *self.table.shape[1:]))

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, key: int | slice) -> torch.Tensor:
        if isinstance(key, slice):
            return self.table[self.index[key]] + self.shift[key][:, None]
        return self.table[int(self.index[key])] + self.shift[key]


def looped_walk(body: Body) -> LoopedWalk:
    """The built-in walk on ``body`` made to loop (module docstring)."""
    motion = load_motion("walk", body)
    rotations, roots = motion.joint_rotations, motion.root_translation
    joints = body.pose(rotations, roots, with_vertices=False).joint_positions  # (T,31,3)
    speed = (roots[1:, :2] - roots[:-1, :2]).norm(dim=-1)
    steady = torch.nonzero(speed >= STEADY_SPEED * speed.max()).flatten()
    start, last = int(steady[0]), int(steady[-1])
    shortest = int(math.ceil(MIN_STRETCH_SECONDS * motion.fps))
    if last - start <= shortest:
        raise ParameterError(f"the walk's steady gait ({last - start} frames) is too short to loop")

    def mismatch(length: int) -> float:
        moved = roots[start + length] - roots[start]
        moved[2] = 0.0
        return float((joints[start + length] - moved - joints[start]).norm(dim=-1).max())

    length = min(range(shortest, last - start + 1), key=mismatch)
    end = start + length
    advance = roots[end] - roots[start]
    advance[2] = 0.0
    # Spread the end-to-start mismatch over the stretch: a share s = i / length at its frame i.
    share = torch.arange(length + 1, dtype=torch.float32) / length
    turn = roma.rotmat_to_rotvec(rotations[end] @ rotations[start].transpose(-1, -2))  # (31,3)
    rotations = rotations[: end + 1].clone()
    rotations[start:] = roma.rotvec_to_rotmat(-share[:, None, None] * turn) @ rotations[start:]
    roots = roots[: end + 1].clone()
    roots[start:, 2] -= share * float(roots[end, 2] - roots[start, 2])
    table = body.pose(rotations[:end], roots[:end])
    step = (joints[start + 1:end + 1] - joints[start:end]).norm(dim=-1).max()
    return LoopedWalk(table, start, length, advance, motion.fps, 1000 * mismatch(length), 1000 * float(step))


@dataclass
class LongRunRecord:
    """One method's long run."""

    method: str
    frames: int
    repeats: int              # how many times the walk's stretch started again
    max_speed: float          # m/s, the fastest garment vertex between two frames
    non_finite: int           # vertex positions with a NaN or infinite coordinate, over all frames
    ms_median: float
    ms_p95: float
    rss_early_mb: float       # resident memory after frame min(EARLY_FRAME, frames)
    rss_end_mb: float         # after the last frame
    early_frame: int


def resident_mb() -> float:
    """This process's resident memory now (MB): /proc/self/status VmRSS; where there is no
    /proc, the peak so far (``resource``)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def long_run(methods: list[str], garment: str = "dress", *, frames: int = 10_000, vertices: int | None = 1500,
             body: str | None = None, device: str = "auto", checkpoint: str | None = None,
             progress: bool = True, report=None) -> tuple[LoopedWalk, list[LongRunRecord]]:
    """Run each method ``frames`` frames on the looping walk; one record each. ``report``,
    when given, is called with each record as its run ends."""
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ParameterError(f"unknown method(s) {unknown}; available: {', '.join(METHODS)}")
    if frames < 2:
        raise ParameterError(f"--frames must be >= 2, got {frames}")
    the_device = pick_device(device)
    the_body = body_for(BodyShape.parse(body))
    walk = looped_walk(the_body)
    posed = walk.posed(frames)
    draped, rest_vertices = draped_garment(garment, the_body, vertices=vertices)
    records = []
    for method in methods:
        solver = METHODS[method](draped, the_body, rest_vertices=rest_vertices, material=draped.material,
                                 checkpoint=checkpoint, device=str(the_device))
        record = _stream(method, solver.frames(posed), frames, walk, the_device, progress)
        records.append(record)
        if report:
            report(record)
        del solver
    return walk, records


def _stream(method: str, stream, frames: int, walk: LoopedWalk, device: torch.device,
            progress: bool) -> LongRunRecord:
    """Draw ``frames`` frames from ``stream``, timing each and keeping only running figures."""
    milliseconds = np.empty(frames)
    max_step, non_finite = 0.0, 0
    early = min(EARLY_FRAME, frames)
    previous, previous_finite, rss_early = None, None, math.nan
    with torch.no_grad():
        for t in tqdm(range(frames), desc=method, unit="frame", disable=not progress, mininterval=5.0):
            synchronize(device)
            started = time.perf_counter()
            vertices = next(stream)
            synchronize(device)
            milliseconds[t] = 1000.0 * (time.perf_counter() - started)
            finite = torch.isfinite(vertices).all(dim=-1)
            non_finite += int((~finite).sum())
            if previous is not None:
                moved = (vertices - previous).norm(dim=-1)[finite & previous_finite]
                if moved.numel():
                    max_step = max(max_step, float(moved.max()))
            previous, previous_finite = vertices.clone(), finite
            if t + 1 == early:
                rss_early = resident_mb()
    return LongRunRecord(method, frames, walk.repeats(frames), max_step * walk.fps, non_finite,
                         statistics.median(milliseconds), float(np.percentile(milliseconds, 95)),
                         rss_early, resident_mb(), early)


TABLE_HEADER = ("| method | frames | looped | max speed m/s | NaN/inf | ms/frame median | ms/frame p95 | "
                "RSS MB @ early frame | RSS MB @ last frame | RSS growth MB |\n"
                "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|")


def table_row(record: LongRunRecord) -> str:
    looped = f"yes, {record.repeats}x" if record.repeats else "no (too few frames)"
    return (f"| {record.method} | {record.frames} | {looped} | {record.max_speed:.2f} | {record.non_finite} | "
            f"{record.ms_median:.2f} | {record.ms_p95:.2f} | {record.rss_early_mb:.0f} (frame {record.early_frame}) | "
            f"{record.rss_end_mb:.0f} (frame {record.frames}) | {record.rss_end_mb - record.rss_early_mb:+.0f} |")
