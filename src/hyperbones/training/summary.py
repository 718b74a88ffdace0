"""A markdown summary of a run's TensorBoard log: each loss term's median per stretch of steps."""

from __future__ import annotations

import statistics
from pathlib import Path

TERMS = ("loss", "stretching", "bending", "gravity", "inertia", "collision", "friction",  # the teacher's
         "a_mse", "a_stretching", "a_bending", "a_collision", "a_interpenetration", "a_laplacian",  # Module A's
         "a_edge_length",
         "grad_norm", "collision_weight", "rollout", "learning_rate", "steps_per_second")


def read_log(log_dir: str | Path) -> dict[str, list[tuple[int, float, float]]]:
    """{tag without the "train/" prefix: [(step, wall time s, value), ...]} from every event
    file under ``log_dir`` (read once; ``training_summary`` and ``training_seconds`` take it)."""
    import logging

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    # A resumed run's log restarts at its checkpoint's step (purge_step); TensorBoard then
    # logs a multi-line notice per resume that says nothing the summary needs.
    logging.getLogger("tensorboard").setLevel(logging.ERROR)
    accumulator = EventAccumulator(str(log_dir), size_guidance={"scalars": 0})
    accumulator.Reload()
    return {tag.removeprefix("train/"): [(e.step, e.wall_time, e.value) for e in accumulator.Scalars(tag)]
            for tag in accumulator.Tags()["scalars"]}


def training_summary(log: dict[str, list[tuple[int, float, float]]], rows: int = 12, up_to: int | None = None) -> str:
    """Medians of each term of ``log`` (``read_log``) over ``rows`` equal stretches of the
    logged steps (those up to step ``up_to`` when given: a log may run on past the checkpoint
    exported), as a markdown table."""
    scalars = {tag: [(step, value) for step, _, value in events if up_to is None or step <= up_to]
               for tag, events in log.items()}
    if "loss" not in scalars or not scalars["loss"]:
        return "(no training steps logged)"
    last_step = max(step for step, _ in scalars["loss"])
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


def training_seconds(log: dict[str, list[tuple[int, float, float]]], up_to: int | None = None,
                     longest_gap: float = 600.0) -> float:
    """Wall-clock seconds spent training, from the logged loss's timestamps in ``log``
    (``read_log``; steps up to ``up_to`` when given): the sum of the gaps between consecutive
    logged steps, leaving out gaps over ``longest_gap`` s (a run stopped and resumed later)."""
    events = sorted((step, wall_time) for step, wall_time, _ in log.get("loss", []) if up_to is None or step <= up_to)
    gaps = (later[1] - earlier[1] for earlier, later in zip(events[:-1], events[1:]))
    return float(sum(gap for gap in gaps if 0.0 < gap <= longest_gap))
