"""Markdown tables of retarget fidelity and foot slip, for ``hyperbones check retarget``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hyperbones.body import BodyShape, body_for
from hyperbones.body.skeleton import LIMB_SEGMENTS
from hyperbones.geometry.rotations import rotation_angle_deg
from hyperbones.motion.builtin import BUILTINS, builtin_motion
from hyperbones.motion.bvh import read_bvh
from hyperbones.motion.fidelity import retarget_report
from hyperbones.motion.ground import sole_points, still_frames
from hyperbones.motion.load import capture_rate
from hyperbones.motion.retarget import retarget_bvh


def retarget_tables(paths: list[str], body_text: str | None = None, source_fps: dict[str, float] | None = None) -> str:
    """Fidelity (bone-direction angles) and foot-slip tables for BVH clips, retargeted with blend-in 0.

    ``source_fps`` maps a clip's file stem to its real capture rate, when its header is wrong.
    """
    body = body_for(BodyShape.parse(body_text))
    fidelity = ["| clip | frames | limbs mean ° | limbs p95 ° | worst limb mean ° | worst limb p95 ° | spine mean ° | "
                "neck mean ° |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    slip = ["| clip | steps | slip median cm | slip max cm | slip max cm without foot lock |",
            "|---|---:|---:|---:|---:|"]
    for path in paths:
        stem = Path(path).stem
        fps = capture_rate(path, source_fps)
        clip = read_bvh(path)
        motion = retarget_bvh(path, body, source_fps=fps)
        report = retarget_report(motion, body, clip, source_fps=fps)
        raw = retarget_report(retarget_bvh(path, body, source_fps=fps, lock_feet_in_stance=False), body, clip, fps)
        seg = report["segments"]
        worst_mean = max(seg[name].mean for name in LIMB_SEGMENTS)
        worst_p95 = max(seg[name].p95 for name in LIMB_SEGMENTS)
        fidelity.append(f"| {stem} | {motion.num_frames} | {report['limb_mean']:.2f} | {report['limb_p95']:.2f} | "
                        f"{worst_mean:.2f} | {worst_p95:.2f} | {seg['spine'].mean:.2f} | {seg['neck'].mean:.2f} |")
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


def builtin_table(body_text: str | None = None, hold: float = 1.0) -> str:
    """Smoothness and ground contact of every built-in clip (default parameters plus a hold)."""
    body = body_for(BodyShape.parse(body_text))
    rows = ["| clip | frames | max joint rotation step ° | lowest sole cm | highest still foot cm | still-foot frames |",
            "|---|---:|---:|---:|---:|---:|"]
    for name in BUILTINS:
        motion = builtin_motion(name, body, hold=hold)
        posed = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=False)
        step = float(rotation_angle_deg(motion.joint_rotations[1:], motion.joint_rotations[:-1]).max())
        lowest, still_max, still_count = float("inf"), 0.0, 0
        for points in sole_points(body, posed.skinning_transforms).values():
            heights = points[..., 2].amin(-1)
            still = still_frames(points, motion.fps)
            lowest = min(lowest, float(heights.min()))
            still_count += int(still.sum())
            if still.any():
                still_max = max(still_max, float(heights[still].max()))
        rows.append(f"| {name} | {motion.num_frames} | {step:.1f} | {lowest * 100:.2f} | {still_max * 100:.2f} | "
                    f"{still_count} |")
    return (f"Built-in clips on body {body.shape.label()} with a {hold:g} s hold. A still foot: its sole centre moves "
            "slower than 5 cm/s for at least 3 frames; it must touch the ground (< 1 cm).\n\n" + "\n".join(rows))
