"""``hyperbones view``: the browser viewer."""

from __future__ import annotations

import time
from pathlib import Path

from hyperbones.cli import options
from hyperbones.errors import InputFileError, ParameterError


def run_view(args) -> int:
    from hyperbones.body.shape import BodyShape
    from hyperbones.garment.templates import TEMPLATES
    from hyperbones.motion.builtin import BUILTINS
    from hyperbones.viewer.app import Viewer
    from hyperbones.viewer.choice import VIEW_METHODS, Choice

    garments, motions = args.garment or [], args.motion or []
    for path in [name for name in garments if name not in TEMPLATES] + [m for m in motions if m not in BUILTINS]:
        if not Path(path).is_file():
            raise InputFileError(path, "file not found (a garment template, a built-in motion or a file was expected)")
    if args.method not in VIEW_METHODS.values():
        raise ParameterError(f"view --method must be one of {', '.join(VIEW_METHODS.values())}, got {args.method!r}")
    if args.frames < 1:
        raise ParameterError(f"view --frames must be >= 1, got {args.frames}")
    choice = Choice(garment=(garments or ["tshirt"])[0], motion=(motions or ["walk"])[0], method=args.method,
                    body=BodyShape.parse(args.body), vertices=args.vertices, frames=args.frames)
    viewer = Viewer(choice, [*TEMPLATES, *garments], [*BUILTINS, *motions], host=args.host, port=args.port,
                    checkpoint=args.checkpoint, playing=not args.paused)
    print(f"hyperbones view: open http://{args.host}:{viewer.port} in a browser (Ctrl-C stops it)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    finally:
        viewer.close()


def add_view(sub) -> None:
    view = sub.add_parser(
        "view", help="a browser viewer: pick garment, motion, method, body shape and fabric, and watch",
        description="Serves a page (viser) showing a garment on an Anny body in motion, with controls: the "
                    "garment (templates and the files given), the motion (built-ins and the .bvh files given), "
                    "the method, six body-shape sliders and three fabric sliders (each a factor of the default "
                    "cloth), play, pause and a frame slider. A change makes the new scene in the background "
                    "(body, drape, Module B's encoding, every frame; progress on the page) while the last one "
                    "plays on.")
    view.add_argument("--garment", action="append", default=None,
                      help="a template or a garment file (.obj with UVs, MakeHuman .mhclo) to offer; repeatable, "
                           "the first is shown first (default: tshirt)")
    view.add_argument("--motion", action="append", default=None,
                      help="a built-in motion or a CMU .bvh file to offer; repeatable, the first is shown first "
                           "(default: walk)")
    view.add_argument("--method", default="hyperbones", help="hyperbones or lbs (default: hyperbones)")
    options.add_body(view)
    view.add_argument("--vertices", type=int, default=2500,
                      help="template resolution in vertices (default: 2500, so that a new body or fabric is "
                           "draped in seconds rather than a minute)")
    view.add_argument("--frames", type=int, default=300,
                      help="the first N frames of each motion (default: 300, ten seconds)")
    options.add_checkpoint(view)
    view.add_argument("--host", default="127.0.0.1", help="address to serve on (default: 127.0.0.1, this machine)")
    view.add_argument("--port", type=int, default=8080, help="port to serve on (default: 8080)")
    view.add_argument("--paused", action="store_true", help="start paused")
    view.set_defaults(func=run_view)


VERBS = (add_view,)
