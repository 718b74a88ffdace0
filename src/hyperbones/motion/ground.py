"""Ground contact of a posed body: sole heights, stance detection, foot slip."""

from __future__ import annotations

import torch

from hyperbones.body.anny_body import Body

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


def contact_slides(points: torch.Tensor, contact_height: float) -> tuple[torch.Tensor, torch.Tensor]:
    """How the part of a foot touching the ground slides between frames.

    Args:
        points: (T,n,3) posed sole vertices of one foot.
        contact_height: a vertex lower than this touches the ground.

    Returns:
        (T-1,2) mean horizontal displacement of the vertices touching in both frames (zero
        when none are: the foot rolled onto another part), and (T,) whether any vertex touches.
    """
    touching = points[..., 2] < contact_height
    both = (touching[1:] & touching[:-1]).float()
    moved = points[1:, :, :2] - points[:-1, :, :2]
    count = both.sum(-1, keepdim=True)
    slide = (moved * both[..., None]).sum(1) / count.clamp(min=1)
    return slide, touching.any(-1)


def planted(points: torch.Tensor, fps: float, contact_height: float, max_speed: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Stance detection for one foot: near the ground and slow.

    Args:
        points: (T,n,3) posed sole vertices.

    Returns:
        (T-1,2) slides (see ``contact_slides``) and (T,) stance flags: some sole vertex lower
        than ``contact_height`` while the sole centre moves slower than ``max_speed`` m/s
        (a swinging foot may skim the floor, but it is not standing on it).
    """
    slide, touching = contact_slides(points, contact_height)
    centre = points[..., :2].mean(1)
    speed = (centre[1:] - centre[:-1]).norm(dim=-1) * fps
    speed = torch.cat([speed[:1], speed]) if len(speed) else torch.zeros(len(points))
    return slide, touching & (speed < max_speed)


def foot_slip_per_step(
    body: Body,
    skinning_transforms: torch.Tensor,
    fps: float,
    contact_height: float = 0.015,
    max_speed: float = 1.0,
    min_frames: int = 3,
) -> list[dict]:
    """How far the part of each foot that touches the ground slides during each step.

    A sole vertex touches the ground when it is lower than ``contact_height``; a foot is in
    stance while any of its sole vertices touches and it moves slower than ``max_speed``
    (see ``planted``). A step's slip is the length of the path
    the touching part slides along over the stance (see ``contact_slides``), so a planted
    foot that rolls heel to toe scores ~0.

    Args:
        body: the body.
        skinning_transforms: (T,31,4,4).

    Returns:
        One dict per step: {"side", "start", "stop", "slip"} (frames, metres).
    """
    steps = []
    for side, points in sole_points(body, skinning_transforms).items():
        slide, stance = planted(points, fps, contact_height, max_speed)
        length = slide.norm(dim=-1)
        for start, stop in stance_intervals(stance, min_frames):
            steps.append({"side": side, "start": start, "stop": stop, "slip": float(length[start:stop - 1].sum())})
    return steps


def still_frames(points: torch.Tensor, fps: float, max_speed: float = 0.05, min_frames: int = 3) -> torch.Tensor:
    """(T,n,3) sole vertices -> (T,) frames inside runs of >= ``min_frames`` where the sole centre
    moves slower than ``max_speed`` m/s (a foot standing still, which must be on the ground)."""
    centre = points.mean(1)
    speed = torch.cat([torch.zeros(1), (centre[1:] - centre[:-1]).norm(dim=-1) * fps])
    still = torch.zeros(len(points), dtype=torch.bool)
    for start, stop in stance_intervals(speed < max_speed, min_frames):
        still[start:stop] = True
    return still
