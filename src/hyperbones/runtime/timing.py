"""Benchmark records and their table, shared by ``bench`` and ``bench-runtime`` (torch only)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch


@dataclass
class BenchRecord:
    method: str
    garment: str
    vertices: int
    device: str
    batch: int
    ms_per_frame: float


def synchronize(device: torch.device) -> None:
    """Wait for queued CUDA work, so the clock reads when it is done."""
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
