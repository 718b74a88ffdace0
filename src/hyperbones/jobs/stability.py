"""``hyperbones check teacher``: long-rollout stability and settling of a learnt method.

Two tables:
  - stability: every garment on each held-out clip, held still to a total of ``frames``
    frames: finite positions, the fastest vertex (m/s), the kinetic energy of the last frame;
  - settling: a built-in clip followed by ``hold`` seconds of stillness: the garment's
    kinetic energy when the body stops and 1 and 2 seconds later.
"""

from __future__ import annotations

import math

from tqdm import tqdm

from hyperbones.body.anny_body import body_for
from hyperbones.body.shape import BodyShape
from hyperbones.jobs.simulate import run_simulation
from hyperbones.motion.load import capture_rate, load_motion
from hyperbones.physics.sequence_metrics import kinetic_energy, runaway_problem


def stability_table(method: str, garments: list[str], motions: list[str], *, frames: int = 1000,
                    vertices: int | None = None, body: str | None = None, checkpoint: str | None = None,
                    device: str = "auto", source_fps: dict[str, float] | None = None, progress: bool = True) -> str:
    the_body = body_for(BodyShape.parse(body))
    rows = ["| garment | motion | frames | finite | max speed m/s | runaway | KE last frame J | ε_c % | ε_e % |",
            "|---|---|---:|---|---:|---|---:|---:|---:|"]
    for garment in tqdm(garments, desc="stability", disable=not progress):
        for motion in motions:
            rate = capture_rate(motion, source_fps)
            length = load_motion(motion, the_body, source_fps=rate).num_frames
            hold = max(0, frames - length) / 30.0
            result = run_simulation(method, garment, motion, body, frames=frames, vertices=vertices, hold=hold,
                                    checkpoint=checkpoint, device=device, source_fps=rate)
            m = result.metrics
            energy = kinetic_energy(result.garment_vertices.double(), result.vertex_masses, 1.0 / result.fps)
            rows.append(f"| {garment} | {m['motion']} | {m['frames']} | {m['finite']} | {m['max_speed']:.2f} | "
                        f"{'yes' if runaway_problem(m) else 'no'} | {float(energy[-1]):.2e} | "
                        f"{m['collision_pct']:.3f} | {m['edge_error_pct']:.2f} |")
    return "\n".join(rows)


def settling_table(method: str, garments: list[str], motion: str = "walk", *, hold: float = 3.0,
                   vertices: int | None = None, body: str | None = None, checkpoint: str | None = None,
                   device: str = "auto", source_fps: dict[str, float] | None = None, progress: bool = True) -> str:
    the_body = body_for(BodyShape.parse(body))
    rate = capture_rate(motion, source_fps)
    stop = load_motion(motion, the_body, source_fps=rate).num_frames - 1  # the last moving frame
    rows = [f"Kinetic energy (J) of the garment after the body stops ({motion} + {hold:g} s hold).", "",
            "| garment | at stop | +0.5 s | +1 s | +2 s | +2 s / at stop |", "|---|---:|---:|---:|---:|---:|"]
    for garment in tqdm(garments, desc="settling", disable=not progress):
        result = run_simulation(method, garment, motion, body, vertices=vertices, hold=hold, checkpoint=checkpoint,
                                device=device, source_fps=rate)
        energy = kinetic_energy(result.garment_vertices.double(), result.vertex_masses, 1.0 / result.fps)
        fps = result.fps
        at = [float(energy[min(len(energy) - 1, stop - 1 + int(round(s * fps)))]) for s in (0.0, 0.5, 1.0, 2.0)]
        ratio = at[3] / at[0] if at[0] > 0 else math.nan
        rows.append(f"| {garment} | {at[0]:.2e} | {at[1]:.2e} | {at[2]:.2e} | {at[3]:.2e} | {ratio:.3f} |")
    return "\n".join(rows)
