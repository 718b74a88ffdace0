"""Markdown tables of retarget fidelity and foot slip, for ``hyperbones check-retarget``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hyperbones.body import BodyShape, body_for
from hyperbones.body.skeleton import LIMB_SEGMENTS
from hyperbones.motion.bvh import read_bvh
from hyperbones.motion.fidelity import retarget_report
from hyperbones.motion.retarget import retarget_bvh


def retarget_tables(paths: list[str], body_text: str | None = None, source_fps: dict[str, float] | None = None) -> str:
    """Fidelity (bone-direction angles) and foot-slip tables for BVH clips, retargeted with blend-in 0.

    ``source_fps`` maps a clip's file stem to its real capture rate, when its header is wrong.
    """
    body = body_for(BodyShape.parse(body_text))
    source_fps = source_fps or {}
    fidelity = ["| clip | frames | limbs mean ° | limbs p95 ° | worst limb p95 ° | spine mean ° | neck mean ° |",
                "|---|---:|---:|---:|---:|---:|---:|"]
    slip = ["| clip | steps | slip median cm | slip max cm | slip max cm without foot lock |",
            "|---|---:|---:|---:|---:|"]
    for path in paths:
        stem = Path(path).stem
        fps = source_fps.get(stem)
        clip = read_bvh(path)
        motion = retarget_bvh(path, body, source_fps=fps)
        report = retarget_report(motion, body, clip, source_fps=fps)
        raw = retarget_report(retarget_bvh(path, body, source_fps=fps, lock_feet_in_stance=False), body, clip, fps)
        seg = report["segments"]
        worst = max(seg[name].p95 for name in LIMB_SEGMENTS)
        fidelity.append(f"| {stem} | {motion.num_frames} | {report['limb_mean']:.2f} | {report['limb_p95']:.2f} | "
                        f"{worst:.2f} | {seg['spine'].mean:.2f} | {seg['neck'].mean:.2f} |")
        slips = np.array([s["slip"] for s in report["steps"]]) * 100
        raw_slips = np.array([s["slip"] for s in raw["steps"]]) * 100
        if len(slips):
            slip.append(f"| {stem} | {len(slips)} | {np.median(slips):.2f} | {slips.max():.2f} | "
                        f"{raw_slips.max() if len(raw_slips) else 0:.2f} |")
        else:
            slip.append(f"| {stem} | 0 | - | - | - |")
    return ("Bone-direction error of the posed Anny skeleton against the BVH, per frame "
            f"(body {body.shape.label()}, 30 fps, blend-in 0):\n\n" + "\n".join(fidelity) +
            "\n\nFoot slip per step (sole vertices < 1.5 cm above the ground and the sole centre "
            "slower than 1 m/s count as stance; slip = path length of the touching part):\n\n" + "\n".join(slip))
