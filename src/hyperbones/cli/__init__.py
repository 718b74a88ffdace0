"""The ``hyperbones`` command line: per verb one small parser builder and one thin function
that calls a job (``hyperbones.jobs``) or the library; options several verbs share are
declared once in ``cli.options``."""

from __future__ import annotations

import argparse
import sys
import warnings

from hyperbones.errors import HyperbonesError

from hyperbones.io_utils import is_output_fault


def build_parser() -> argparse.ArgumentParser:
    from hyperbones.cli import animation, check, engine, garments, simulation, training, viewer

    parser = argparse.ArgumentParser(
        prog="hyperbones",
        description="Garments that move with an animated body in real time. Units: metres, Z up, 30 fps.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for group in (simulation, animation, viewer, engine, garments, training, check):
        for add in group.VERBS:
            add(sub)
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
    except OSError as error:
        # A writer outside hyperbones' own (TensorBoard's log, a folder made for a run) that the
        # disk or the folder refused: the user's environment, not a bug.
        if not is_output_fault(error):
            raise
        place = f"{error.filename}: " if error.filename else ""
        print(f"hyperbones: error: {place}{error.strerror or error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hyperbones: interrupted", file=sys.stderr)
        return 130
