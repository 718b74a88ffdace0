"""Benchmark records, the frame timer and the tables, shared by ``bench`` and ``bench-runtime`` (torch only)."""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import asdict, dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from hyperbones.errors import ParameterError


@dataclass
class BenchRecord:
    """One timed block of one method on one garment (or crowd).

    ms_per_frame, p95_ms: the median and the 95th percentile of the per-frame times (per
    character-frame when ``batch`` > 1: a batch's frame time over ``batch``).
    stages: {runtime stage: mean ms per frame, in the same unit} from ``bench --profile``;
    empty for methods without the per-frame runtime, for blocks not profiled, or without it.
    """

    method: str
    garment: str
    vertices: int
    device: str
    batch: int
    ms_per_frame: float
    p95_ms: float
    from_frame: int = 0  # the first timed frame (index into the motion)
    stages: dict[str, float] = field(default_factory=dict)


class TimedBlock(NamedTuple):
    """What ``timed_blocks`` measured over one block of frames (milliseconds per frame)."""

    first: int  # the block's first frame
    median: float
    p95: float  # 95th percentile (linear interpolation between the frames' times)


def synchronize(device: torch.device) -> None:
    """Wait for queued CUDA work, so the clock reads when it is done."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed_blocks(step: Callable[[int], None], device: torch.device, warmup: int, frames: int,
                 late: int | None = None, *, prepare: Callable[[int], None] | None = None,
                 around: Callable[[int], AbstractContextManager] | None = None) -> list[TimedBlock]:
    """Call ``step(t)`` for t = 0, 1, … and time it (CUDA synchronised): the median and 95th
    percentile of the ``frames`` frames from ``warmup`` on and, with ``late``, of the ``frames``
    frames from ``late`` on (frames between the two blocks run untimed).

    prepare: ``prepare(t)`` runs before every ``step(t)``, off the clock: what a frame needs
    that is not the timed method's work (``bench --batch`` gathers the crowd's posed bodies).
    around: ``around(i)`` is a context manager entered just before block ``i``'s first timed
    frame and left after its last, off the clock (``bench --profile`` attaches a stage clock
    to the first block only).
    """
    starts = [warmup] if late is None else [warmup, late]
    if late is not None and late < warmup + frames:
        raise ParameterError(f"--late {late} must come after the first timed block "
                             f"(frames {warmup}–{warmup + frames - 1})")
    blocks = []
    t = 0
    for index, first in enumerate(starts):
        while t < first:
            if prepare is not None:
                prepare(t)
            step(t)
            t += 1
        times = np.empty(frames)
        with around(index) if around is not None else nullcontext():
            for i in range(frames):
                if prepare is not None:
                    prepare(t)
                synchronize(device)
                start = time.perf_counter()
                step(t)
                synchronize(device)
                times[i] = 1000.0 * (time.perf_counter() - start)
                t += 1
        blocks.append(TimedBlock(first, float(np.median(times)), float(np.percentile(times, 95))))
    return blocks


def bench_table(records: list[BenchRecord]) -> str:
    """The records as a Markdown table (ms per character-frame where batch > 1)."""
    lines = ["| method | garment | vertices | device | batch | from frame | ms/frame (median) | p95 |",
             "|---|---|---:|---|---:|---:|---:|---:|"]
    lines += [f"| {r.method} | {r.garment} | {r.vertices} | {r.device} | {r.batch} | {r.from_frame} | "
              f"{r.ms_per_frame:.2f} | {r.p95_ms:.2f} |" for r in records]
    return "\n".join(lines)


def stage_table(record: BenchRecord) -> str:
    """``record``'s runtime stages as a Markdown table: ms per frame and share of the median
    frame, a total over the stages, and the median frame itself (what the stages leave out of
    it is the frame's own bookkeeping; their mean may also differ from its median)."""
    unit = "ms/character-frame" if record.batch > 1 else "ms/frame"
    frame = record.ms_per_frame

    def share(ms: float) -> str:
        return f"{100.0 * ms / frame:.1f}" if frame > 0 else "-"

    lines = [f"{record.method} on {record.garment} ({record.vertices} vertices, {record.device}, batch "
             f"{record.batch}): stages over the frames from {record.from_frame} on",
             f"| stage | {unit} | share of the frame (%) |", "|---|---:|---:|"]
    lines += [f"| {name} | {ms:.3f} | {share(ms)} |" for name, ms in record.stages.items()]
    total = sum(record.stages.values())
    lines += [f"| total of the stages | {total:.3f} | {share(total)} |",
              f"| frame (median) | {frame:.3f} | {share(frame)} |"]
    return "\n".join(lines)


def speedups(records: list[BenchRecord], fast: str = "hyperbones", slow: str = "teacher") -> list[str]:
    """One line per garment timed with both methods: how many times faster ``fast`` is (medians)."""
    timed = {(r.method, r.garment, r.vertices, r.device, r.from_frame): r.ms_per_frame for r in records}
    return [f"{fast} is {timed[(slow, g, v, d, f)] / ms:.1f}x faster than the {slow} on {g} ({v} vertices, {d}, "
            f"frames from {f})"
            for (method, g, v, d, f), ms in timed.items() if method == fast and (slow, g, v, d, f) in timed]


def records_as_dicts(records: list[BenchRecord]) -> list[dict]:
    return [asdict(r) for r in records]
