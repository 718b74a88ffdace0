"""Verbs about motion alone: motion (write a posed skeleton) and render (a motion on the body)."""

from __future__ import annotations

import time

from hyperbones.cli import options
from hyperbones.errors import ParameterError


def _add_motion_source(parser) -> None:
    from hyperbones.motion import BUILTINS, DEFAULT_FPS

    parser.add_argument("source", nargs="?", default="walk",
                        help=f"a built-in motion ({', '.join(BUILTINS)}) or a CMU .bvh file (default: walk)")
    options.add_body(parser)
    options.add_blend_in(parser)
    parser.add_argument("--speed", type=float, default=None,
                        help="built-in motions: walk/run in m/s (default 1.2/2.5 for the default body, in proportion "
                             "to leg length for others), turn in turns/s, others a tempo factor")
    parser.add_argument("--duration", type=float, default=None, help="built-in motions: seconds of motion")
    options.add_hold(parser)
    parser.add_argument("--fps", type=float, default=DEFAULT_FPS, help=f"output frame rate (default: {DEFAULT_FPS:g})")
    options.add_source_fps(parser)


def _load(args):
    from hyperbones.body import BodyShape, body_for
    from hyperbones.motion import load_motion

    body = body_for(BodyShape.parse(args.body))
    motion = load_motion(args.source, body, fps=args.fps, blend_in=args.blend_in, speed=args.speed,
                         duration=args.duration, hold=args.hold, source_fps=args.source_fps)
    return body, motion


def run_motion(args) -> int:
    from hyperbones.motion import BUILTINS, save_motion_npz

    if args.list:
        for name, spec in BUILTINS.items():
            print(f"{name:10s} {spec.description} (speed in {spec.speed_unit}, default {spec.default_speed:g}; "
                  f"duration {spec.default_duration:g} s)")
        return 0
    if args.out is None:
        raise ParameterError("motion: --out FILE.npz is required")
    body, motion = _load(args)
    path = save_motion_npz(motion, body, args.out)
    print(f"wrote {path} ({motion.num_frames} frames, {motion.duration:.2f} s at {motion.fps:g} fps)")
    return 0


def add_motion(sub) -> None:
    motion = sub.add_parser("motion", help="write a motion (built-in or BVH, retargeted to a body) to .npz",
                            description="Write the posed skeleton of a motion: joint_names, joint_positions (T,31,3), "
                                        "joint_rotations (T,31,3,3), fps.")
    _add_motion_source(motion)
    motion.add_argument("--out", default=None, help="output .npz file")
    motion.add_argument("--list", action="store_true", help="list the built-in motions and exit")
    motion.set_defaults(func=run_motion)


def run_render(args) -> int:
    from hyperbones.viz.scene import render_motion

    body, motion = _load(args)
    start = time.perf_counter()
    video, sheet = render_motion(body, motion, args.out, size=args.size, progress=not args.quiet)
    took = time.perf_counter() - start
    print(f"wrote {video} and {sheet} ({motion.num_frames} frames = {motion.duration:.1f} s of motion "
          f"rendered in {took:.1f} s)")
    return 0


def add_render(sub) -> None:
    render = sub.add_parser("render", help="render a motion on the body to MP4 plus a PNG contact sheet")
    _add_motion_source(render)
    options.add_out(render, "output .mp4 (the sheet is written beside it)")
    render.add_argument("--size", type=int, default=512, help="frame size in pixels (default: 512)")
    options.add_quiet(render)
    render.set_defaults(func=run_render)


VERBS = (add_motion, add_render)
