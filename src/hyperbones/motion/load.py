"""One entry point for every motion source: a built-in name or a CMU .bvh file."""

from __future__ import annotations

import math
from pathlib import Path

from hyperbones.body.anny_body import Body
from hyperbones.errors import InputFileError, ParameterError
from hyperbones.motion.builtin import BUILTINS, builtin_motion
from hyperbones.motion.bvh import MAX_FPS, MIN_FPS
from hyperbones.motion.motion import DEFAULT_FPS, Motion
from hyperbones.motion.retarget import retarget_bvh

DEFAULT_BLEND_IN = 15


def load_motion(
    source: str,
    body: Body,
    *,
    fps: float = DEFAULT_FPS,
    blend_in: int = DEFAULT_BLEND_IN,
    speed: float | None = None,
    duration: float | None = None,
    hold: float = 0.0,
    source_fps: float | None = None,
) -> Motion:
    """Load a motion fitted to ``body``.

    Args:
        source: a built-in name (see ``hyperbones.motion.builtin.BUILTINS``) or a path to a
            CMU BVH file.
        fps: frame rate of the result.
        blend_in: frames of transition from the A-pose prepended (0: none).
        speed, duration: built-in clip parameters (defaults per clip).
        hold: seconds of stillness appended at the end.
        source_fps: override of a BVH header's frame rate.
    """
    if blend_in < 0:
        raise ParameterError(f"--blend-in must be >= 0 frames, got {blend_in}")
    if not 0 < fps <= MAX_FPS:  # also refuses NaN
        raise ParameterError(f"--fps must be positive and at most {MAX_FPS:g}, got {fps}")
    if not 0 <= hold < math.inf:
        raise ParameterError(f"--hold must be >= 0, got {hold}")
    if source_fps is not None and not MIN_FPS <= source_fps <= MAX_FPS:
        raise ParameterError(f"--source-fps must lie in [{MIN_FPS:g}, {MAX_FPS:g}] frames per second, got {source_fps}")
    if source in BUILTINS:
        motion = builtin_motion(source, body, speed=speed, duration=duration, hold=0.0, fps=fps)
    elif source.lower().endswith(".bvh") or Path(source).exists():
        if speed is not None or duration is not None:
            raise ParameterError("--speed and --duration apply to built-in motions, not to BVH files")
        if Path(source).suffix.lower() != ".bvh":
            raise InputFileError(source, "not a .bvh file (motion files must be CMU BVH)")
        try:
            motion = retarget_bvh(source, body, fps=fps, source_fps=source_fps)
        except ParameterError as error:  # the options are checked above: the clip itself is unusable
            raise InputFileError(source, f"cannot be retargeted: {error}") from None
    else:
        raise ParameterError(f"unknown motion {source!r}: give a built-in name ({', '.join(BUILTINS)}) or a .bvh file")
    return motion.blend_in(blend_in, body.rest_root).with_hold(int(round(hold * fps)))


def capture_rate(source: str, rates: dict[str, float] | None) -> float | None:
    """The real capture rate ``rates`` gives a motion by its file stem (e.g. ``{"74_06": 60}``
    for ``.../74_06.bvh``), or None: the header's rate (or a built-in motion)."""
    return (rates or {}).get(Path(source).stem) if source.lower().endswith(".bvh") else None
