"""A markdown summary of a run's TensorBoard log: each loss term's median per stretch of steps."""

from __future__ import annotations

import statistics
from pathlib import Path

TERMS = ("loss", "stretching", "bending", "gravity", "inertia", "collision", "friction", "grad_norm",
         "collision_weight", "rollout", "steps_per_second")


def read_scalars(log_dir: str | Path) -> dict[str, list[tuple[int, float]]]:
    """{tag without the "train/" prefix: [(step, value), ...]} from every event file under ``log_dir``."""
    import logging

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    # A resumed run's log restarts at its checkpoint's step (purge_step); TensorBoard then
    # logs a multi-line notice per resume that says nothing the summary needs.
    logging.getLogger("tensorboard").setLevel(logging.ERROR)
    accumulator = EventAccumulator(str(log_dir), size_guidance={"scalars": 0})
    accumulator.Reload()
    out = {}
    for tag in accumulator.Tags()["scalars"]:
        out[tag.removeprefix("train/")] = [(event.step, event.value) for event in accumulator.Scalars(tag)]
    return out


def training_summary(log_dir: str | Path, rows: int = 12) -> str:
    """Medians of each term over ``rows`` equal stretches of the logged steps, as a markdown table."""
    scalars = read_scalars(log_dir)
    if "loss" not in scalars or not scalars["loss"]:
        return "(no training steps logged)"
    last_step = scalars["loss"][-1][0]
    edges = [round(last_step * i / rows) for i in range(rows + 1)]
    terms = [t for t in TERMS if t in scalars]
    lines = ["| steps | " + " | ".join(terms) + " |", "|---|" + "---:|" * len(terms)]
    for low, high in zip(edges[:-1], edges[1:]):
        cells = []
        for term in terms:
            values = [v for step, v in scalars[term] if low < step <= high]
            cells.append(f"{statistics.median(values):.4g}" if values else "-")
        lines.append(f"| {low + 1}–{high} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
