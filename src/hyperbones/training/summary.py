"""A markdown summary of a run's TensorBoard log: each loss term's median per stretch of steps."""

from __future__ import annotations

import statistics
from pathlib import Path

TERMS = ("loss", "stretching", "bending", "gravity", "inertia", "collision", "friction",  # the teacher's
         "a_mse", "a_stretching", "a_bending", "a_collision", "a_interpenetration", "a_laplacian",  # Module A's
         "grad_norm", "collision_weight", "rollout", "learning_rate", "steps_per_second")


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


def training_summary(log_dir: str | Path, rows: int = 12, up_to: int | None = None) -> str:
    """Medians of each term over ``rows`` equal stretches of the logged steps (those up to
    step ``up_to`` when given: a log may run on past the checkpoint exported), as a markdown table."""
    scalars = read_scalars(log_dir)
    if up_to is not None:
        scalars = {tag: [(step, v) for step, v in values if step <= up_to] for tag, values in scalars.items()}
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


def training_seconds(log_dir: str | Path, up_to: int | None = None, longest_gap: float = 600.0) -> float:
    """Wall-clock seconds spent training, from the logged loss's timestamps (steps up to
    ``up_to`` when given): the sum of the gaps between consecutive logged steps, leaving out
    gaps over ``longest_gap`` s (a run stopped and resumed later)."""
    import logging

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    logging.getLogger("tensorboard").setLevel(logging.ERROR)
    accumulator = EventAccumulator(str(log_dir), size_guidance={"scalars": 0})
    accumulator.Reload()
    if "train/loss" not in accumulator.Tags()["scalars"]:
        return 0.0
    events = sorted((e.step, e.wall_time) for e in accumulator.Scalars("train/loss")
                    if up_to is None or e.step <= up_to)
    gaps = (later[1] - earlier[1] for earlier, later in zip(events[:-1], events[1:]))
    return float(sum(gap for gap in gaps if 0.0 < gap <= longest_gap))
