"""Ground contact of a posed body: sole heights, stance detection, foot slip."""

from __future__ import annotations

import torch

from hyperbones.body.anny_body import Body
from hyperbones.body.skeleton import JOINT_INDEX

SIDES = ("left", "right")


def sole_points(body: Body, skinning_transforms: torch.Tensor) -> dict[str, torch.Tensor]:
    """Posed sole vertices of each foot.

    Args:
        body: the body (its ``foot_vertex_indices`` select the soles).
        skinning_transforms: (T,31,4,4) from ``Body.pose``.

    Returns:
        {"left","right"}: (T,n,3) world positions.
    """
    return {side: body.skin_points(body.foot_vertex_indices[side], skinning_transforms) for side in SIDES}


def sole_heights(body: Body, skinning_transforms: torch.Tensor) -> torch.Tensor:
    """(T,31,4,4) skinning transforms -> (T,2) lowest sole height of the left and right foot, metres."""
    points = sole_points(body, skinning_transforms)
    return torch.stack([points[side][..., 2].amin(-1) for side in SIDES], dim=-1)


def stance_intervals(in_contact: torch.Tensor, min_frames: int = 3) -> list[tuple[int, int]]:
    """(T,) bool contact flags -> [start, stop) runs of at least ``min_frames`` frames."""
    flags = in_contact.tolist() + [False]
    intervals, start = [], None
    for i, flag in enumerate(flags):
        if flag and start is None:
            start = i
        elif not flag and start is not None:
            if i - start >= min_frames:
                intervals.append((start, i))
            start = None
    return intervals


def foot_slip_per_step(
    body: Body,
    skinning_transforms: torch.Tensor,
    contact_height: float = 0.015,
    min_frames: int = 3,
) -> list[dict]:
    """How far the part of each foot that touches the ground slides during each step.

    A sole vertex touches the ground when it is lower than ``contact_height``; a foot is in
    stance while any of its sole vertices touches. Between two consecutive stance frames,
    the slide is the mean horizontal displacement of the vertices touching in both frames
    (none in common: the foot rolled onto another part, no slide counted). A step's slip
    is the sum of its slides, so a planted foot that rolls heel to toe scores ~0.

    Args:
        body: the body.
        skinning_transforms: (T,31,4,4).

    Returns:
        One dict per step: {"side", "start", "stop", "slip"} (frames, metres).
    """
    steps = []
    for side, points in sole_points(body, skinning_transforms).items():
        touching = points[..., 2] < contact_height  # (T,n)
        both = touching[1:] & touching[:-1]
        moved = (points[1:, :, :2] - points[:-1, :, :2]).norm(dim=-1)
        count = both.sum(-1)
        slide = torch.where(count > 0, (moved * both).sum(-1) / count.clamp(min=1), torch.zeros_like(moved[:, 0]))
        for start, stop in stance_intervals(touching.any(-1), min_frames):
            steps.append({"side": side, "start": start, "stop": stop,
                          "slip": float(slide[start:stop - 1].sum())})
    return steps
