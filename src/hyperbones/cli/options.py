"""Options several verbs share, each declared once, with choices and defaults taken from the code."""

from __future__ import annotations

import argparse

from hyperbones.errors import ParameterError

BODY_HELP = ("body shape as phenotype values in [0,1]: gender, age, muscle, weight, height, proportions, "
             "e.g. 'gender=0.2,weight=0.8' (default: all 0.5)")
RUNTIME_HELP = ("runtime settings over the checkpoint's as key=value pairs, e.g. 'follow=0.5,untangle=false' "
                "(hyperbones methods; the keys are the fields of hyperbones.runtime.config.RuntimeConfig)")
MATERIAL_HELP = "cloth: mu, lambda (Pa), thickness (m), density (kg/m2), bending, e.g. 'mu=30000' (default: HOOD's)"


def comma_list(text: str) -> list[str]:
    """A comma-separated option as its non-empty, stripped items."""
    return [item.strip() for item in text.split(",") if item.strip()]


def template_names() -> list[str]:
    from hyperbones.garment.templates import TEMPLATES

    return list(TEMPLATES)


def method_names() -> list[str]:
    from hyperbones.jobs.methods import METHODS

    return list(METHODS)


def add_out(parser: argparse.ArgumentParser, help: str, default: str | None = None) -> None:
    parser.add_argument("--out", required=default is None, default=default,
                        help=help if default is None else f"{help} (default: {default})")


def add_body(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--body", default=None, help=BODY_HELP)


def add_device(parser: argparse.ArgumentParser, default: str = "auto") -> None:
    parser.add_argument("--device", default=default, help=f"cpu, cuda or auto: CUDA when present (default: {default})")


def add_set(parser: argparse.ArgumentParser) -> None:
    """--set SECTION.KEY=VALUE (repeatable): one training-config field overridden (``training.config.apply_overrides``)."""
    parser.add_argument("--set", action="append", default=None, metavar="SECTION.KEY=VALUE",
                        help="override one config field, e.g. train.steps=500 or data.train_clips='[\"01_01\"]' "
                             "(repeatable; the value is read as TOML, else as text)")


def add_quiet(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def add_checkpoint(parser: argparse.ArgumentParser, help: str = "checkpoint for the learnt methods (default: the "
                   "shipped ones; a HyperBones checkpoint holds its teacher too)") -> None:
    parser.add_argument("--checkpoint", default=None, help=help)


def add_vertices(parser: argparse.ArgumentParser) -> None:
    from hyperbones.garment.templates import DEFAULT_VERTICES

    parser.add_argument("--vertices", type=int, default=None,
                        help=f"template resolution in vertices (default: {DEFAULT_VERTICES})")


def add_garment(parser: argparse.ArgumentParser, default: str = "dress") -> None:
    parser.add_argument("--garment", default=default,
                        help=f"a template ({', '.join(template_names())}), an .obj with UVs fitted to the default "
                             f"body, or a MakeHuman .mhclo (default: {default})")


def add_garments(parser: argparse.ArgumentParser, default: str | None = None) -> None:
    default = default or ",".join(template_names())
    parser.add_argument("--garments", default=default, help=f"comma list of garments (default: {default})")


def add_methods(parser: argparse.ArgumentParser, default: str) -> None:
    parser.add_argument("--methods", default=default,
                        help=f"comma list of methods: {', '.join(method_names())} (default: {default})")


def add_runtime(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--runtime", default=None, metavar="KEY=VALUE,...", help=RUNTIME_HELP)


def add_material(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--material", default=None, help=MATERIAL_HELP)


def add_uv_resolution(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--uv-resolution", type=int, default=None,
                        help="UV map size R of the hyperbones methods (default: the one the model was trained at)")


def add_blend_in(parser: argparse.ArgumentParser) -> None:
    from hyperbones.motion.load import DEFAULT_BLEND_IN

    parser.add_argument("--blend-in", type=int, default=DEFAULT_BLEND_IN, metavar="N",
                        help=f"frames of transition from the A-pose at the start, 0 disables (default: "
                             f"{DEFAULT_BLEND_IN})")


def add_hold(parser: argparse.ArgumentParser, default: float = 0.0) -> None:
    parser.add_argument("--hold", type=float, default=default,
                        help=f"seconds of stillness appended to the motion (default: {default:g})")


def parse_source_fps(text: str) -> float:
    """``--source-fps FPS``: a capture rate in frames per second, within the BVH reader's range."""
    from hyperbones.motion.bvh import MAX_FPS, MIN_FPS

    try:
        fps = float(text)
    except ValueError:
        raise ParameterError(f"--source-fps: expected a number of frames per second, got {text!r}") from None
    if not MIN_FPS <= fps <= MAX_FPS:  # also refuses NaN
        raise ParameterError(f"--source-fps: {text!r} is outside [{MIN_FPS:g}, {MAX_FPS:g}] frames per second")
    return fps


def parse_source_fps_pair(text: str) -> tuple[str, float]:
    """``--source-fps CLIP=FPS``: a clip's file stem and its capture rate."""
    name, equals, value = text.partition("=")
    if not equals or not name.strip():
        raise ParameterError(f"--source-fps: expected CLIP=FPS (e.g. 74_06=60), got {text!r}")
    return name.strip(), parse_source_fps(value.strip())


class _SourceFpsAction(argparse.Action):
    """Parses the value itself: argparse reports a ``type=`` error after its usage lines, and the
    CLI's errors are one line (``hyperbones: error: ...``, status 2)."""

    def __call__(self, parser, namespace, values, option_string=None):
        try:
            self.store(namespace, values)
        except ParameterError as error:
            parser.exit(2, f"hyperbones: error: {error}\n")

    def store(self, namespace, text: str) -> None:
        setattr(namespace, self.dest, parse_source_fps(text))


class _SourceFpsPairsAction(_SourceFpsAction):
    def store(self, namespace, text: str) -> None:
        setattr(namespace, self.dest, [*(getattr(namespace, self.dest) or []), parse_source_fps_pair(text)])


def add_source_fps(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source-fps", action=_SourceFpsAction, default=None, metavar="FPS",
                        help="BVH only: the real capture rate when the header is wrong (CMU 74_06, 143_06: 60)")


def add_source_fps_pairs(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source-fps", action=_SourceFpsPairsAction, default=None, metavar="CLIP=FPS",
                        help="real capture rate of a BVH clip (by file stem) whose header is wrong, e.g. 74_06=60 "
                             "(repeatable; CMU 74_06 and 143_06 are 60 fps captures with 120 fps headers)")


def source_fps_pairs(args) -> dict[str, float]:
    """``--source-fps CLIP=FPS`` options as {clip: fps}."""
    return dict(args.source_fps or [])
