"""Benchmark records, the frame timer and the table, shared by ``bench`` and ``bench-runtime`` (torch only)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import torch

from hyperbones.errors import ParameterError


@dataclass
class BenchRecord:
    method: str
    garment: str
    vertices: int
    device: str
    batch: int
    ms_per_frame: float
    from_frame: int = 0  # the first timed frame (index into the motion)


def synchronize(device: torch.device) -> None:
    """Wait for queued CUDA work, so the clock reads when it is done."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed_blocks(step: Callable[[int], None], device: torch.device, warmup: int, frames: int,
                 late: int | None = None) -> list[tuple[int, float]]:
    """Call ``step(t)`` for t = 0, 1, … and time it (CUDA synchronised): the median ms of the
    ``frames`` frames from ``warmup`` on and, with ``late``, of the ``frames`` frames from
    ``late`` on (frames between the two blocks run untimed). Returns [(first frame, median)]."""
    starts = [warmup] if late is None else [warmup, late]
    if late is not None and late < warmup + frames:
        raise ParameterError(f"--late {late} must come after the first timed block "
                             f"(frames {warmup}–{warmup + frames - 1})")
    blocks = []
    t = 0
    for first in starts:
        while t < first:
            step(t)
            t += 1
        times = []
        for _ in range(frames):
            synchronize(device)
            start = time.perf_counter()
            step(t)
            synchronize(device)
            times.append(1000.0 * (time.perf_counter() - start))
            t += 1
        blocks.append((first, statistics.median(times)))
    return blocks


def bench_table(records: list[BenchRecord]) -> str:
    lines = ["| method | garment | vertices | device | batch | from frame | ms/frame |",
             "|---|---|---:|---|---:|---:|---:|"]
    lines += [f"| {r.method} | {r.garment} | {r.vertices} | {r.device} | {r.batch} | {r.from_frame} | "
              f"{r.ms_per_frame:.2f} |" for r in records]
    return "\n".join(lines)


def speedups(records: list[BenchRecord], fast: str = "hyperbones", slow: str = "teacher") -> list[str]:
    """One line per garment timed with both methods: how many times faster ``fast`` is."""
    timed = {(r.method, r.garment, r.vertices, r.device, r.from_frame): r.ms_per_frame for r in records}
    return [f"{fast} is {timed[(slow, g, v, d, f)] / ms:.1f}x faster than the {slow} on {g} ({v} vertices, {d}, "
            f"frames from {f})"
            for (method, g, v, d, f), ms in timed.items() if method == fast and (slow, g, v, d, f) in timed]


def records_as_dicts(records: list[BenchRecord]) -> list[dict]:
    return [asdict(r) for r in records]
