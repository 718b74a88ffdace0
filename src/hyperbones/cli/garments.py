"""The garment verb: ``garment make`` writes a template fitted (and draped) on a body."""

from __future__ import annotations

import math
from pathlib import Path

from hyperbones.cli import options


def run_garment_make(args) -> int:
    from hyperbones.body import BodyShape, body_for
    from hyperbones.garment import make_template, write_obj_garment
    from hyperbones.garment.drape import drape

    body = body_for(BodyShape.parse(args.body))
    garment = make_template(args.type, body, args.vertices)
    note = "not draped"
    if not args.no_drape:
        garment, report = drape(garment, body)
        rest = "at rest" if report.converged else "NOT at rest"
        last_step = "" if math.isnan(report.newton_step_max) else (
            f", last Newton step {1000 * report.newton_step_max:.3f} mm")
        note = (f"draped in {report.iterations} Newton iterations, {rest} (95 % of free vertices carry an "
                f"unbalanced force under {report.force_ratio_p95:.3f} of their weight{last_step}); edge error "
                f"{report.edge_error_pct:.2f} %, penetrating vertices {report.penetrating_before} -> "
                f"{report.penetrating_after}")
    path = write_obj_garment(args.out, garment) or args.out
    print(f"wrote {Path(path).resolve()} ({garment.num_vertices} vertices, {len(garment.faces)} triangles, "
          f"{len(garment.pinned)} pinned; {note})")
    return 0


def add_garment(sub) -> None:
    from hyperbones.garment.templates import DEFAULT_VERTICES

    garment = sub.add_parser("garment", help="make the built-in garments")
    actions = garment.add_subparsers(dest="garment_command", metavar="ACTION", required=True)
    make = actions.add_parser("make", help="a template fitted (and draped) on a body, written as OBJ")
    make.add_argument("type", choices=options.template_names(), help="the template")
    options.add_body(make)
    make.add_argument("--vertices", type=int, default=DEFAULT_VERTICES,
                      help=f"about this many vertices (1000-40000, default: {DEFAULT_VERTICES})")
    options.add_out(make, "output .obj")
    make.add_argument("--no-drape", action="store_true", help="write the fitted template without draping it")
    make.set_defaults(func=run_garment_make)


VERBS = (add_garment,)
