"""The ``hyperbones`` command line: one verb per job, each a thin call into the library."""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

from hyperbones.errors import HyperbonesError

BODY_HELP = ("body shape as phenotype values in [0,1]: gender, age, muscle, weight, height, proportions, "
             "e.g. 'gender=0.2,weight=0.8' (default: all 0.5)")


def _add_motion_args(parser: argparse.ArgumentParser) -> None:
    from hyperbones.motion import BUILTINS, DEFAULT_BLEND_IN

    names = ", ".join(BUILTINS)
    parser.add_argument("source", nargs="?", default="walk",
                        help=f"a built-in motion ({names}) or a CMU .bvh file (default: walk)")
    parser.add_argument("--body", default=None, help=BODY_HELP)
    parser.add_argument("--blend-in", type=int, default=DEFAULT_BLEND_IN, metavar="N",
                        help=f"frames of transition from the A-pose at the start, 0 disables (default: {DEFAULT_BLEND_IN})")
    parser.add_argument("--speed", type=float, default=None,
                        help="built-in motions: walk/run in m/s (default 1.2/2.5 for the default body, in proportion to leg length for others), turn in turns/s, others a tempo factor")
    parser.add_argument("--duration", type=float, default=None, help="built-in motions: seconds of motion")
    parser.add_argument("--hold", type=float, default=0.0, help="seconds of stillness appended at the end")
    parser.add_argument("--fps", type=float, default=30.0, help="output frame rate (default: 30)")
    parser.add_argument("--source-fps", type=float, default=None,
                        help="BVH only: the real capture rate when the header is wrong (some CMU trials: 60)")


def _load(args):
    from hyperbones.body import BodyShape, body_for
    from hyperbones.motion import load_motion

    body = body_for(BodyShape.parse(args.body))
    motion = load_motion(args.source, body, fps=args.fps, blend_in=args.blend_in, speed=args.speed,
                         duration=args.duration, hold=args.hold, source_fps=args.source_fps)
    return body, motion


def cmd_motion(args) -> int:
    from hyperbones.motion import BUILTINS, save_motion_npz

    if args.list:
        for name, spec in BUILTINS.items():
            print(f"{name:10s} {spec.description} (speed in {spec.speed_unit}, default {spec.default_speed:g}; "
                  f"duration {spec.default_duration:g} s)")
        return 0
    if args.out is None:
        raise HyperbonesError("motion: --out FILE.npz is required")
    body, motion = _load(args)
    path = save_motion_npz(motion, body, args.out)
    print(f"wrote {path} ({motion.num_frames} frames, {motion.duration:.2f} s at {motion.fps:g} fps)")
    return 0


def cmd_render(args) -> int:
    from hyperbones.viz.scene import render_motion

    body, motion = _load(args)
    start = time.perf_counter()
    video, sheet = render_motion(body, motion, args.out, size=args.size, progress=not args.quiet)
    took = time.perf_counter() - start
    print(f"wrote {video} and {sheet} ({motion.num_frames} frames = {motion.duration:.1f} s of motion "
          f"rendered in {took:.1f} s)")
    return 0


def cmd_demo(args) -> int:
    from hyperbones.body import Body
    from hyperbones.motion import load_motion, save_motion_npz
    from hyperbones.viz.scene import render_motion

    out = Path(args.out).resolve()
    start = time.perf_counter()
    print("hyperbones demo: building the default Anny body (the first run on a machine builds Anny's cache, ~1 min)")
    body = Body()
    motion = load_motion("walk", body, hold=1.0)
    npz = save_motion_npz(motion, body, out / "motion.npz")
    video, sheet = render_motion(body, motion, out / "preview.mp4", progress=not args.quiet)
    print(f"done in {time.perf_counter() - start:.1f} s:\n  video  {video}\n  sheet  {sheet}\n  motion {npz}")
    return 0


def cmd_check_retarget(args) -> int:
    from hyperbones.motion.report import retarget_tables

    print(retarget_tables(args.bvh, args.body, source_fps=dict(args.source_fps or [])))
    return 0


def cmd_check_builtins(args) -> int:
    from hyperbones.motion.report import builtin_table

    print(builtin_table(args.body, hold=args.hold))
    return 0


def _source_fps_pair(text: str):
    name, _, value = text.partition("=")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected CLIP=FPS, got {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hyperbones",
        description="Garments that move with an animated body in real time. Units: metres, Z up, 30 fps.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    demo = sub.add_parser("demo", help="run the main job on built-in data and write its outputs")
    demo.add_argument("--out", default="hyperbones-demo", help="output folder (default: ./hyperbones-demo)")
    demo.add_argument("--quiet", action="store_true", help="no progress bars")
    demo.set_defaults(func=cmd_demo)

    motion = sub.add_parser("motion", help="write a motion (built-in or BVH, retargeted to a body) to .npz",
                            description="Write the posed skeleton of a motion: joint_names, joint_positions (T,31,3), "
                                        "joint_rotations (T,31,3,3), fps.")
    _add_motion_args(motion)
    motion.add_argument("--out", default=None, help="output .npz file")
    motion.add_argument("--list", action="store_true", help="list the built-in motions and exit")
    motion.set_defaults(func=cmd_motion)

    render = sub.add_parser("render", help="render a motion on the body to MP4 plus a PNG contact sheet")
    _add_motion_args(render)
    render.add_argument("--out", required=True, help="output .mp4 (the sheet is written beside it)")
    render.add_argument("--size", type=int, default=512, help="frame size in pixels (default: 512)")
    render.add_argument("--quiet", action="store_true", help="no progress bar")
    render.set_defaults(func=cmd_render)

    check = sub.add_parser("check-retarget", help="tables of retarget fidelity and foot slip for BVH clips")
    check.add_argument("bvh", nargs="+", help="CMU .bvh files")
    check.add_argument("--body", default=None, help=BODY_HELP)
    check.add_argument("--source-fps", type=_source_fps_pair, action="append", metavar="CLIP=FPS",
                       help="capture rate of a clip whose header is wrong, e.g. 74_06=60 (repeatable)")
    check.set_defaults(func=cmd_check_retarget)

    builtins = sub.add_parser("check-builtins", help="table of smoothness and ground contact of the built-in motions")
    builtins.add_argument("--body", default=None, help=BODY_HELP)
    builtins.add_argument("--hold", type=float, default=1.0, help="seconds of hold appended (default: 1)")
    builtins.set_defaults(func=cmd_check_builtins)
    return parser


def _one_line_warnings(message, category, filename, lineno, file=None, line=None):
    print(f"hyperbones: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    warnings.showwarning = _one_line_warnings
    try:
        return args.func(args)
    except HyperbonesError as error:
        print(f"hyperbones: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hyperbones: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
