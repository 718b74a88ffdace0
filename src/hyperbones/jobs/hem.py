"""``hyperbones check hem``: does the hem keep moving after the body stops?

Each method simulates a garment through a clip followed by a hold (the body stands still).
The hem is the lowest 5 % of the canonical garment's vertices. Reported per method:
  - the hem's mean displacement from where it finally rests, over time since the stop;
  - how long after the stop the hem keeps moving: the last time its mean speed is above
    ``STILL_SPEED`` (a skinned garment stops with the body, a simulated one swings on).
The curves are plotted to a PNG.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from hyperbones.body.anny_body import body_for
from hyperbones.body.shape import BodyShape
from hyperbones.io_utils import atomic_path
from hyperbones.jobs.simulate import run_simulation
from hyperbones.motion.load import capture_rate, load_motion

HEM_FRACTION = 0.05
STILL_SPEED = 0.02  # m/s: mean hem speed under which the hem counts as still


@dataclass
class HemCurve:
    """One method's hem after the stop: times (s since the stop), displacement (m), speed (m/s)."""

    method: str
    times: torch.Tensor
    displacement: torch.Tensor
    speed: torch.Tensor

    def displacement_at(self, seconds: float) -> float:
        """Displacement (m) ``seconds`` after the stop (the last frame if the curve is shorter)."""
        return float(self.displacement[int(torch.searchsorted(self.times, seconds).clamp(max=len(self.times) - 1))])

    @property
    def moving_for(self) -> float:
        """Seconds after the stop until the hem's speed stays under ``STILL_SPEED``."""
        moving = torch.nonzero(self.speed > STILL_SPEED).squeeze(1)
        return float(self.times[moving[-1]]) if len(moving) else 0.0


def hem_curves(methods: list[str], garment: str = "dress", motion: str = "walk", *, hold: float = 2.0,
               vertices: int | None = None, body: str | None = None, checkpoint: str | None = None,
               device: str = "auto", source_fps: dict[str, float] | None = None,
               runtime: str | None = None) -> list[HemCurve]:
    the_body = body_for(BodyShape.parse(body))
    rate = capture_rate(motion, source_fps)
    stop = load_motion(motion, the_body, source_fps=rate).num_frames - 1  # the last frame the body moves into
    curves = []
    for method in methods:
        result = run_simulation(method, garment, motion, body, vertices=vertices, hold=hold, checkpoint=checkpoint,
                                device=device, source_fps=rate, runtime=runtime)
        canonical = result.garment.vertices
        hem = torch.argsort(canonical[:, 2])[: max(1, int(HEM_FRACTION * len(canonical)))]
        track = result.garment_vertices[stop:, hem].double()  # (T',H,3) from the stop on
        displacement = (track - track[-1]).norm(dim=-1).mean(-1)
        speed = torch.cat([torch.zeros(1, dtype=track.dtype),
                           (track[1:] - track[:-1]).norm(dim=-1).mean(-1) * result.fps])
        times = torch.arange(len(track), dtype=torch.float64) / result.fps
        curves.append(HemCurve(method, times, displacement, speed))
    return curves


def hem_table(curves: list[HemCurve]) -> str:
    rows = ["| method | hem moving after the stop (s) | displacement at stop (mm) | at +0.3 s (mm) | at +1 s (mm) |",
            "|---|---:|---:|---:|---:|"]
    for curve in curves:
        at = [curve.displacement_at(seconds) * 1e3 for seconds in (0.0, 0.3, 1.0)]
        rows.append(f"| {curve.method} | {curve.moving_for:.2f} | {at[0]:.1f} | {at[1]:.1f} | {at[2]:.1f} |")
    return "\n".join(rows)


def plot_hem(curves: list[HemCurve], path: str | Path, title: str) -> Path:
    """Hem displacement (mm) over time since the stop, one line per method, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    figure, axis = plt.subplots(figsize=(7, 4), dpi=120)
    for curve in curves:
        axis.plot(curve.times.numpy(), curve.displacement.numpy() * 1e3,
                  label=f"{curve.method} (moving {curve.moving_for:.2f} s)")
    axis.axvline(0.3, color="grey", linestyle=":", linewidth=1)
    axis.set_xlabel("time since the body stopped (s)")
    axis.set_ylabel("hem displacement from rest (mm)")
    axis.set_title(title)
    axis.legend()
    figure.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png")
    plt.close(figure)
    return path
