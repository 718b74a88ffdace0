"""``hyperbones check …``: the diagnostic tables (retarget, built-in motions, drape, teacher
stability, hem), each a job in ``hyperbones.jobs`` that prints a markdown table."""

from __future__ import annotations

from pathlib import Path

from hyperbones.cli import options
from hyperbones.errors import ParameterError


def run_retarget(args) -> int:
    from hyperbones.jobs.motion_report import retarget_tables

    print(retarget_tables(args.bvh, args.body, source_fps=options.source_fps_pairs(args)))
    return 0


def add_retarget(checks) -> None:
    retarget = checks.add_parser("retarget", help="tables of retarget fidelity and foot slip for BVH clips")
    retarget.add_argument("bvh", nargs="+", help="CMU .bvh files")
    options.add_body(retarget)
    options.add_source_fps_pairs(retarget)
    retarget.set_defaults(func=run_retarget)


def run_builtins(args) -> int:
    from hyperbones.jobs.motion_report import builtin_table

    print(builtin_table(args.body, hold=args.hold))
    return 0


def add_builtins(checks) -> None:
    builtins = checks.add_parser("builtins", help="table of smoothness and ground contact of the built-in motions")
    options.add_body(builtins)
    options.add_hold(builtins, default=1.0)
    builtins.set_defaults(func=run_builtins)


def run_drape(args) -> int:
    from hyperbones.body import BodyShape
    from hyperbones.garment.templates import TEMPLATES
    from hyperbones.jobs.drape_report import CORNER_BODIES, HEADER, drape_rows

    try:
        resolutions = [int(v) for v in options.comma_list(args.resolutions)]
    except ValueError:
        raise ParameterError(f"--resolutions must be a comma list of vertex counts, got {args.resolutions!r}") from None
    templates = options.comma_list(args.templates)
    unknown = sorted(set(templates) - set(TEMPLATES))
    if unknown:
        raise ParameterError(f"--templates: unknown template(s) {unknown}; available: {', '.join(TEMPLATES)}")
    bodies = args.bodies.split(";") if args.bodies is not None else list(CORNER_BODIES)
    for body in bodies:
        BodyShape.parse(body)  # a bad body fails before any drape, not after an hour of them
    print(HEADER, flush=True)
    for row in drape_rows(resolutions, bodies, [Path(p) for p in args.mhclo], templates, progress=not args.quiet):
        print(row, flush=True)  # each row as its drape ends: a long table shows its results as it goes
    return 0


def add_drape(checks) -> None:
    drape = checks.add_parser("drape", help="table of drape quality over garments, resolutions and bodies",
                              description="Drapes every template (at each --resolutions) and every piece of the "
                                          "given MakeHuman .mhclo files on the default body, then on each body, and "
                                          "prints collision, edge/area error and strain against the rest shape; a "
                                          "strain over twice the default body's, also once divided by the rest "
                                          "area's ratio squared, is marked ✗.")
    drape.add_argument("mhclo", nargs="*", help="MakeHuman .mhclo garments to include (every piece)")
    drape.add_argument("--resolutions", default="1500",
                       help="template vertex counts (comma list; empty: no templates; default: 1500)")
    drape.add_argument("--templates", default=",".join(options.template_names()),
                       help="procedural templates to include (comma list; empty: none; default: all)")
    drape.add_argument("--bodies", default=None,
                       help="body shapes separated by ';' (default: the eight corners of gender, weight, height in "
                            "{0.1, 0.9}); the default body is always draped first, as the strain reference")
    options.add_quiet(drape)
    drape.set_defaults(func=run_drape)


def run_teacher(args) -> int:
    from hyperbones.jobs.stability import settling_table, stability_table

    garments = options.comma_list(args.garments)
    common = dict(vertices=args.vertices, body=args.body, checkpoint=args.checkpoint, device=args.device,
                  source_fps=options.source_fps_pairs(args), progress=not args.quiet)
    print(stability_table(args.method, garments, options.comma_list(args.motions), frames=args.frames, **common))
    print()
    print(settling_table(args.method, garments, args.settle_motion, hold=args.hold, **common))
    return 0


def add_teacher(checks) -> None:
    teacher = checks.add_parser("teacher", help="tables of long-rollout stability and settling of a learnt method",
                                description="Rolls the method out for --frames frames on each motion (held still "
                                            "after it ends) and reports NaN, top speed and kinetic energy; then "
                                            "measures how the garment's kinetic energy decays after a clip stops.")
    teacher.add_argument("--method", default="teacher",
                         help=f"one of {', '.join(options.method_names())} (default: teacher)")
    options.add_checkpoint(teacher)
    options.add_garments(teacher)
    teacher.add_argument("--motions", default="walk", help="comma list of motions for the long rollouts "
                                                           "(default: walk)")
    teacher.add_argument("--frames", type=int, default=1000, help="rollout length (default: 1000)")
    teacher.add_argument("--settle-motion", default="walk", help="clip before the still hold (default: walk)")
    options.add_hold(teacher, default=3.0)
    options.add_vertices(teacher)
    options.add_body(teacher)
    options.add_device(teacher)
    options.add_source_fps_pairs(teacher)
    options.add_quiet(teacher)
    teacher.set_defaults(func=run_teacher)


def run_hem(args) -> int:
    from hyperbones.jobs.hem import hem_curves, hem_table, plot_hem

    curves = hem_curves(options.comma_list(args.methods), args.garment, args.motion, hold=args.hold,
                        vertices=args.vertices, body=args.body, checkpoint=args.checkpoint, device=args.device,
                        source_fps=options.source_fps_pairs(args), runtime=args.runtime)
    print(hem_table(curves))
    out = plot_hem(curves, args.out, f"{args.garment} hem after {args.motion} stops")
    print(f"wrote {out.resolve()}")
    return 0


def add_hem(checks) -> None:
    hem = checks.add_parser("hem", help="does the hem keep swinging after the body stops? table + PNG",
                            description="Simulates the garment through the motion and a hold with each method, "
                                        "then reports how long the hem (lowest 5 %% of the garment) keeps moving "
                                        "after the body stops and plots its displacement to --out.")
    options.add_methods(hem, default="lbs,teacher,hyperbones")
    options.add_garment(hem)
    hem.add_argument("--motion", default="walk", help="clip that ends with the stop (default: walk)")
    options.add_hold(hem, default=2.0)
    options.add_vertices(hem)
    options.add_body(hem)
    options.add_checkpoint(hem)
    options.add_device(hem)
    options.add_runtime(hem)
    options.add_out(hem, "PNG to write", default="hem.png")
    options.add_source_fps_pairs(hem)
    hem.set_defaults(func=run_hem)


def run_long(args) -> int:
    from hyperbones.jobs.long_run import TABLE_HEADER, long_run, table_row

    methods = options.comma_list(args.methods)
    printed = []

    def report(record) -> None:  # each row as its run ends: a long check shows results as it goes
        if not printed:
            print(TABLE_HEADER, flush=True)
            printed.append(True)
        print(table_row(record), flush=True)

    walk, _ = long_run(methods, args.garment, frames=args.frames, vertices=args.vertices, body=args.body,
                       device=args.device, checkpoint=args.checkpoint, progress=not args.quiet, report=report)
    print()
    print(walk.describe())
    return 0


def add_long(checks) -> None:
    long = checks.add_parser("long", help="table of speed, NaN, timing and memory over a long looping walk",
                             description="Runs each method for --frames frames of the built-in walk made to loop "
                                         "(one stretch of its steady gait repeated, the join smoothed), streaming "
                                         "the frames, and prints per method: the fastest garment vertex, non-finite "
                                         "positions, ms per frame (median, p95) and resident memory at frame 100 "
                                         "and at the last frame.")
    options.add_methods(long, default="hyperbones,teacher")
    options.add_garment(long)
    long.add_argument("--vertices", type=int, default=1500, help="template resolution in vertices (default: 1500)")
    long.add_argument("--frames", type=int, default=10_000, help="frames per method (default: 10000)")
    options.add_body(long)
    options.add_device(long)
    options.add_checkpoint(long)
    options.add_quiet(long)
    long.set_defaults(func=run_long)


def add_check(sub) -> None:
    check = sub.add_parser("check", help="diagnostic tables: retarget, builtins, drape, teacher, hem, long",
                           description="Diagnostic jobs, each printing a markdown table.")
    checks = check.add_subparsers(dest="check_command", metavar="CHECK", required=True)
    for add in (add_retarget, add_builtins, add_drape, add_teacher, add_hem, add_long):
        add(checks)


VERBS = (add_check,)
