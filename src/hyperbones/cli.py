"""The ``hyperbones`` command line: one verb per job, each a thin call into the library."""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

from hyperbones.errors import HyperbonesError, InputFileError, ParameterError

RUNTIME_HELP = ("runtime settings over the checkpoint's as key=value pairs, e.g. 'follow=0.5,untangle=false' "
                "(hyperbones methods; the keys are RuntimeConfig's fields: hyperbones.runtime.config)")
BODY_HELP = ("body shape as phenotype values in [0,1]: gender, age, muscle, weight, height, proportions, "
             "e.g. 'gender=0.2,weight=0.8' (default: all 0.5)")


def _comma_list(text: str) -> list[str]:
    """A comma-separated option as its non-empty, stripped items."""
    return [item.strip() for item in text.split(",") if item.strip()]


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


def _print_run(result, paths: dict) -> None:
    """One line of what a simulation measured, then where its outputs are."""
    m = result.metrics
    print(f"{m['method']} on {m['garment']} ({m['garment_vertices']} vertices), {m['motion']} ({m['frames']} frames): "
          f"{m['ms_per_frame']:.2f} ms/frame, edge error {m['edge_error_pct']:.2f} %, "
          f"collision {m['collision_pct']:.2f} %")
    for kind, path in paths.items():
        print(f"  {kind:8s} {Path(path).resolve()}")


DEMO_VERTICES = 2500  # the dress at the shipped model's larger training resolution


def cmd_demo(args) -> int:
    from hyperbones.simulate.pipeline import export_simulation, run_simulation

    start = time.perf_counter()
    print("hyperbones demo: the default dress on the default Anny body, walking, then standing still for 1 s,\n"
          "simulated by the shipped HyperBones model (Module B once, then Module A every frame)\n"
          "(the first run on a machine builds Anny's cache and drapes the dress: about a minute more)", flush=True)
    result = run_simulation("hyperbones", "dress", "walk", None, vertices=DEMO_VERTICES, hold=1.0,
                            device=args.device, progress=not args.quiet, runtime=args.runtime)
    paths = export_simulation(result, Path(args.out).resolve(), progress=not args.quiet)
    print(f"done in {time.perf_counter() - start:.1f} s")
    _print_run(result, paths)
    return 0


def cmd_check_retarget(args) -> int:
    from hyperbones.motion.report import retarget_tables

    print(retarget_tables(args.bvh, args.body, source_fps=dict(args.source_fps or [])))
    return 0


def cmd_check_builtins(args) -> int:
    from hyperbones.motion.report import builtin_table

    print(builtin_table(args.body, hold=args.hold))
    return 0


def cmd_simulate(args) -> int:
    from hyperbones.simulate.pipeline import export_simulation, run_simulation

    result = run_simulation(args.method, args.garment, args.motion, args.body, frames=args.frames,
                            vertices=args.vertices, piece=args.piece, material=args.material,
                            blend_in=args.blend_in, hold=args.hold, checkpoint=args.checkpoint, device=args.device,
                            source_fps=args.source_fps, progress=not args.quiet, runtime=args.runtime)
    paths = export_simulation(result, args.out, preview=not args.no_preview, obj=args.obj, progress=not args.quiet)
    _print_run(result, paths)
    return 0


def cmd_garment_make(args) -> int:
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


def cmd_check_drape(args) -> int:
    from hyperbones.body import BodyShape
    from hyperbones.errors import ParameterError
    from hyperbones.garment.report import HEADER, drape_rows
    from hyperbones.garment.templates import TEMPLATES

    try:
        resolutions = [int(v) for v in _comma_list(args.resolutions)]
    except ValueError:
        raise ParameterError(f"--resolutions must be a comma list of vertex counts, got {args.resolutions!r}") from None
    templates = _comma_list(args.templates)
    unknown = sorted(set(templates) - set(TEMPLATES))
    if unknown:
        raise ParameterError(f"--templates: unknown template(s) {unknown}; available: {', '.join(TEMPLATES)}")
    bodies = args.bodies.split(";")
    for body in bodies:
        BodyShape.parse(body)  # a bad body fails before any drape, not after an hour of them
    print(HEADER, flush=True)
    for row in drape_rows(resolutions, bodies, [Path(p) for p in args.mhclo], templates,
                          progress=not args.quiet):
        print(row, flush=True)  # each row as its drape ends: a long table shows its results as it goes
    return 0


def cmd_eval(args) -> int:
    from hyperbones.simulate.evaluate import evaluate

    bodies = [b.strip() for b in args.bodies.split(";")] if args.bodies else [None]
    report = evaluate(_comma_list(args.methods), _comma_list(args.garments), _comma_list(args.motions), bodies,
                      args.out, frames=args.frames, vertices=args.vertices, hold=args.hold, checkpoint=args.checkpoint,
                      device=args.device, source_fps=dict(args.source_fps or []), progress=not args.quiet,
                      uv_resolution=args.uv_resolution, runtime=args.runtime)
    print(report.read_text())
    print(f"wrote {report.resolve()} and {report.with_suffix('.json').resolve()}")
    return 0


def cmd_train(args) -> int:
    from hyperbones.training.config import HyperBonesTrainingConfig, load_config
    from hyperbones.training.joint import JointTrainer
    from hyperbones.training.trainer import TeacherTrainer

    config = load_config(args.config)
    kind = JointTrainer if isinstance(config, HyperBonesTrainingConfig) else TeacherTrainer
    trainer = kind(config, args.out, resume=args.resume, progress=not args.quiet, max_steps=args.max_steps)
    try:
        step = trainer.train()
    except BaseException:
        trainer.close(finished=False)
        raise
    trainer.close()
    if trainer.is_main:
        print(f"trained to step {step}; checkpoint {trainer.checkpoint_path.resolve()}, "
              f"TensorBoard logs {(trainer.run_dir / 'tensorboard').resolve()}")
    return 0


def cmd_export(args) -> int:
    from hyperbones.training.checkpoint import export_weights

    path = export_weights(args.checkpoint, args.out)
    print(f"wrote {Path(path).resolve()}")
    return 0


def _report_records(records, json_path: str | None, notes: list[str]) -> None:
    """Print bench records as a table, then ``notes``; write them to ``json_path`` when given."""
    import json

    from hyperbones.io_utils import atomic_path
    from hyperbones.runtime.timing import bench_table, records_as_dicts

    print(bench_table(records))
    for line in notes:
        print(line)
    if json_path:
        with atomic_path(json_path) as tmp:
            tmp.write_text(json.dumps(records_as_dicts(records), indent=2) + "\n")
        print(f"wrote {Path(json_path).resolve()}")


def cmd_bench(args) -> int:
    from hyperbones.runtime.bench import bench
    from hyperbones.runtime.timing import speedups

    records = bench(_comma_list(args.methods), _comma_list(args.garments), vertices=args.vertices,
                    device=args.device, frames=args.frames, warmup=args.warmup, late=args.late,
                    checkpoint=args.checkpoint, uv_resolution=args.uv_resolution, progress=not args.quiet,
                    runtime=args.runtime)
    _report_records(records, args.json, speedups(records))
    return 0


def cmd_rollouts(args) -> int:
    from hyperbones.training.config import HyperBonesTrainingConfig, load_config
    from hyperbones.training.rollouts import generate_bank

    config = load_config(args.config)
    if not isinstance(config, HyperBonesTrainingConfig):
        raise InputFileError(args.config, "not a HyperBones (phase 2) config: it has no [joint] table")
    out = args.out or config.joint.bank
    if not out:
        raise ParameterError("no --out, and the config's joint.bank is empty")
    if args.templates:
        templates = tuple(_comma_list(args.templates))
        unknown = sorted(set(templates) - set(config.data.templates))
        if unknown:
            raise ParameterError(f"--templates {', '.join(unknown)}: not among the config's data.templates "
                                 f"({', '.join(config.data.templates)})")
        config = replace(config, data=replace(config.data, templates=templates))
    generate_bank(config, out, args.count, seed=args.seed, progress=not args.quiet)
    return 0


def cmd_check_hem(args) -> int:
    from hyperbones.simulate.hem import hem_curves, hem_table, plot_hem

    curves = hem_curves(_comma_list(args.methods), args.garment, args.motion, hold=args.hold, vertices=args.vertices,
                        body=args.body, checkpoint=args.checkpoint, device=args.device,
                        source_fps=dict(args.source_fps or []), runtime=args.runtime)
    print(hem_table(curves))
    out = plot_hem(curves, args.out, f"{args.garment} hem after {args.motion} stops")
    print(f"wrote {out.resolve()}")
    return 0


def cmd_identity(args) -> int:
    import torch

    from hyperbones.body.anny_body import body_for
    from hyperbones.body.shape import BodyShape
    from hyperbones.physics.material import Material
    from hyperbones.runtime.identity import encode_identity
    from hyperbones.runtime.simulator import hyperbones_from_checkpoint
    from hyperbones.simulate.garments import draped_garment

    if args.untrained and args.checkpoint:
        raise ParameterError("--untrained and --checkpoint exclude each other")
    body = body_for(BodyShape.parse(args.body))
    garment, rest_vertices = draped_garment(args.garment, body, vertices=args.vertices, piece=args.piece,
                                            material=Material.parse(args.material))
    if args.untrained:
        from hyperbones.models.hyperbones import HyperBonesModel

        torch.manual_seed(0)
        model = HyperBonesModel().eval()
    else:
        model = hyperbones_from_checkpoint(args.checkpoint)
    with torch.no_grad():
        identity = encode_identity(model, garment, body, uv_resolution=args.uv_resolution,
                                   rest_vertices=rest_vertices)
    out = identity.save(args.out)
    print(f"wrote {out.resolve()} ({identity.num_vertices} vertices, {identity.bones.num_bones} bones, "
          f"UV {identity.raster.resolution}²{', untrained: for timing only' if args.untrained else ''})")
    return 0


def cmd_bench_runtime(args) -> int:
    from hyperbones.runtime.bench_runtime import bench_runtime

    records = bench_runtime(args.identity, args.motion, checkpoint=args.checkpoint, uv_resolution=args.uv_resolution,
                            device=args.device, batch=args.batch, frames=args.frames, warmup=args.warmup,
                            late=args.late)
    _report_records(records, args.json, [] if args.checkpoint else ["(Module A freshly initialised: timing only)"])
    return 0


def cmd_check_teacher(args) -> int:
    from hyperbones.simulate.stability import settling_table, stability_table

    garments = _comma_list(args.garments)
    common = dict(vertices=args.vertices, body=args.body, checkpoint=args.checkpoint, device=args.device,
                  source_fps=dict(args.source_fps or []), progress=not args.quiet)
    print(stability_table(args.method, garments, _comma_list(args.motions), frames=args.frames, **common))
    print()
    print(settling_table(args.method, garments, args.settle_motion, hold=args.hold, **common))
    return 0


def _source_fps_pair(text: str):
    name, _, value = text.partition("=")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected CLIP=FPS, got {text!r}") from None


def _add_source_fps_pairs(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source-fps", type=_source_fps_pair, action="append", metavar="CLIP=FPS",
                        help="real capture rate of a BVH clip (by file stem) whose header is wrong, e.g. 74_06=60 "
                             "(repeatable; CMU 74_06 and 143_06 are 60 fps captures with 120 fps headers)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hyperbones",
        description="Garments that move with an animated body in real time. Units: metres, Z up, 30 fps.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    demo = sub.add_parser("demo", help="simulate the default dress with the shipped model and write every output",
                          description="The default dress (2,500 vertices) on the default Anny body walking, then "
                                      "still for 1 s, simulated by the shipped HyperBones model. Writes "
                                      "preview.mp4 + preview_sheet.png, scene.usd, garment.pc2, frames.npz and "
                                      "metrics.json into --out and prints their paths.")
    demo.add_argument("--out", default="hyperbones-demo", help="output folder (default: ./hyperbones-demo)")
    demo.add_argument("--device", default="auto", help="cpu, cuda or auto (default: CUDA when present)")
    demo.add_argument("--quiet", action="store_true", help="no progress bars")
    demo.add_argument("--runtime", default=None, metavar="KEY=VALUE,...", help=RUNTIME_HELP)
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
    _add_source_fps_pairs(check)
    check.set_defaults(func=cmd_check_retarget)

    simulate = sub.add_parser("simulate", help="simulate a garment on a moving body and export it",
                              description="Writes DIR/frames.npz, garment.pc2, scene.usd, preview.mp4 and metrics.json.")
    simulate.add_argument("--method", default="hyperbones",
                          help="hyperbones (default: the shipped model's per-frame bone runtime: the garment follows "
                               "Module A's output, is pushed out of the body and has its edges pulled back to length "
                               "each frame), lbs (skinning, no dynamics), teacher (the physics-trained MeshGraphNet), "
                               "hyperbones-raw "
                               "(Module A alone) or "
                               "physics (each frame's energy minimised by L-BFGS: slow, the teacher's reference)")
    simulate.add_argument("--checkpoint", default=None,
                          help="teacher or HyperBones checkpoint (default: the one shipped in the package)")
    simulate.add_argument("--device", default="auto", help="cpu, cuda or auto (CUDA when present; default)")
    simulate.add_argument("--garment", default="dress",
                          help="a template (tshirt, tshirt-open, pants, long-skirt, dress, tight-dress), an .obj fitted "
                               "to the default body, or a MakeHuman .mhclo (default: dress)")
    simulate.add_argument("--motion", default="walk", help="a built-in motion or a CMU .bvh file (default: walk)")
    simulate.add_argument("--body", default=None, help=BODY_HELP)
    simulate.add_argument("--out", required=True, help="output folder")
    simulate.add_argument("--frames", type=int, default=None, help="simulate only the first N frames")
    simulate.add_argument("--vertices", type=int, default=None, help="template resolution (default 5000)")
    simulate.add_argument("--piece", type=int, default=None, help="which piece of a multi-piece .mhclo outfit")
    simulate.add_argument("--material", default=None,
                          help="cloth: mu, lambda (Pa), thickness (m), density (kg/m2), bending, e.g. 'mu=30000'")
    simulate.add_argument("--blend-in", type=int, default=15, metavar="N", help="A-pose transition frames (default 15)")
    simulate.add_argument("--hold", type=float, default=0.0, help="seconds of stillness appended to the motion")
    simulate.add_argument("--source-fps", type=float, default=None,
                          help="BVH only: the real capture rate when the header is wrong (CMU 74_06, 143_06: 60)")
    simulate.add_argument("--obj", action="store_true", help="also write an OBJ per frame into DIR/obj/")
    simulate.add_argument("--no-preview", action="store_true", help="skip the preview video")
    simulate.add_argument("--quiet", action="store_true", help="no progress bars")
    simulate.add_argument("--runtime", default=None, metavar="KEY=VALUE,...", help=RUNTIME_HELP)
    simulate.set_defaults(func=cmd_simulate)

    evaluation = sub.add_parser("eval", help="evaluate methods over garments, motions and bodies",
                                description="Writes DIR/report.md (a methods x garments table) and DIR/report.json.")
    evaluation.add_argument("--methods", default="lbs",
                            help="comma list of methods: lbs, teacher, hyperbones, hyperbones-raw (no follow, "
                                 "contact or edge step), physics (default: lbs); physics minimises each frame's energy with "
                                 "L-BFGS, the teacher's slow reference")
    evaluation.add_argument("--checkpoint", default=None,
                            help="teacher or HyperBones checkpoint (default: the shipped ones; a HyperBones one "
                                 "holds its teacher too)")
    evaluation.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    evaluation.add_argument("--hold", type=float, default=0.0, help="seconds of stillness appended to each motion")
    evaluation.add_argument("--garments", default="tshirt,dress,long-skirt,pants", help="comma list of garments")
    evaluation.add_argument("--motions", default="walk,run", help="comma list of motions (built-in names or .bvh)")
    evaluation.add_argument("--bodies", default=None, help="body shapes separated by ';' (default: the default body)")
    evaluation.add_argument("--frames", type=int, default=None, help="only the first N frames of each motion")
    evaluation.add_argument("--vertices", type=int, default=None, help="template resolution")
    evaluation.add_argument("--out", required=True, help="output folder")
    evaluation.add_argument("--uv-resolution", type=int, default=None,
                            help="UV size R of the hyperbones methods (default: the model's training one)")
    _add_source_fps_pairs(evaluation)
    evaluation.add_argument("--quiet", action="store_true", help="no progress bar")
    evaluation.add_argument("--runtime", default=None, metavar="KEY=VALUE,...", help=RUNTIME_HELP)
    evaluation.set_defaults(func=cmd_eval)

    train = sub.add_parser("train", help="train the teacher (phase 1) or all of HyperBones (phase 2), self-supervised",
                           description="Trains from a TOML config. A config with [model], [data], [train] trains the "
                                       "teacher (Module C) on the physics energies (configs/teacher*.toml; under "
                                       "torchrun on every process, DDP); one that also has [runtime] and [joint] "
                                       "trains Modules A, B and C together from a teacher run "
                                       "(configs/hyperbones*.toml, one process). Writes OUT/checkpoint.pt (atomic, "
                                       "every train.checkpoint_every steps, config inside) and TensorBoard logs in "
                                       "OUT/tensorboard.")
    train.add_argument("--config", required=True, help="TOML training config")
    train.add_argument("--out", required=True, help="run folder")
    train.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    train.add_argument("--max-steps", type=int, default=None, help="stop at this step (below train.steps)")
    train.add_argument("--quiet", action="store_true", help="no progress bar")
    train.set_defaults(func=cmd_train)

    export = sub.add_parser("export", aliases=["export-teacher"],
                            help="keep only what inference needs from a training checkpoint (teacher or HyperBones)",
                            description="Writes OUT (the weights' moving average + config + step; loads with "
                                        "weights_only) and OUT with .md: the config, training wall time and a "
                                        "summary of the run's TensorBoard log up to the checkpoint's step.")
    export.add_argument("checkpoint", help="a run's checkpoint.pt")
    export.add_argument("--out", required=True, help="output .pt (model weights + config)")
    export.set_defaults(func=cmd_export)

    bench = sub.add_parser("bench", help="median ms per frame of each method on each garment",
                           description="Times each method frame by frame on the default body walking, after a warm-up "
                                       "(CUDA timings synchronised). Prints a table; --json writes records "
                                       "{method, garment, vertices, device, batch, ms_per_frame, from_frame}.")
    bench.add_argument("--methods", default="lbs,teacher", help="comma list of lbs, teacher, hyperbones, "
                                                                "hyperbones-raw (default: lbs,teacher)")
    bench.add_argument("--garments", default="tshirt,tshirt-open,pants,long-skirt,dress,tight-dress",
                       help="comma list of garments (default: the six templates)")
    bench.add_argument("--vertices", type=int, default=None, help="template resolution (default 5000)")
    bench.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    bench.add_argument("--frames", type=int, default=30, help="timed frames per run (default 30)")
    bench.add_argument("--warmup", type=int, default=5, help="untimed frames first (default 5)")
    bench.add_argument("--late", type=int, default=None,
                       help="also time the --frames frames from this frame on (e.g. 1000), to show that the cost "
                            "per frame does not grow with the motion's length")
    bench.add_argument("--checkpoint", default=None,
                       help="checkpoint for the learnt methods (a HyperBones one holds its teacher too; "
                            "default: the shipped ones)")
    bench.add_argument("--uv-resolution", type=int, default=None,
                       help="UV map size R for hyperbones (default: the one it was trained at)")
    bench.add_argument("--json", default=None, help="also write the records to this JSON file")
    bench.add_argument("--quiet", action="store_true", help="no progress bar")
    bench.add_argument("--runtime", default=None, metavar="KEY=VALUE,...", help=RUNTIME_HELP)
    bench.set_defaults(func=cmd_bench)

    rollouts = sub.add_parser("rollouts", help="simulate teacher rollouts into a bank for phase 2 (joint.bank)",
                              description="Rolls the config's teacher (train.init_from) out over random training "
                                          "identities and clip windows, as phase 2's cache does, and saves each "
                                          "rollout (~1 MB) to the bank folder. Several processes with different "
                                          "--seed values can fill one bank; the same seed goes on where it stopped.")
    rollouts.add_argument("--config", required=True, help="HyperBones (phase 2) TOML config")
    rollouts.add_argument("--out", default=None, help="bank folder (default: the config's joint.bank)")
    rollouts.add_argument("--count", type=int, default=100, help="rollouts to add (default 100)")
    rollouts.add_argument("--seed", type=int, default=0, help="draw seed; one per process sharing a bank (default 0)")
    rollouts.add_argument("--templates", default=None,
                          help="comma list: draw only these of the config's garment templates (default: all), "
                               "to add rollouts of garments the model does worst on")
    rollouts.add_argument("--quiet", action="store_true", help="no progress bar")
    rollouts.set_defaults(func=cmd_rollouts)

    identity = sub.add_parser("identity", help="encode a body x garment once (Module B) and save the identity cache",
                              description="Drapes the garment on the body, runs Module B and writes the cache the "
                                          "per-frame runtime loads (Identity.load, bench-runtime --identity).")
    identity.add_argument("--garment", default="dress", help="template name, .obj or .mhclo (default: dress)")
    identity.add_argument("--vertices", type=int, default=None, help="template resolution (default 5000)")
    identity.add_argument("--piece", type=int, default=None, help="piece of a multi-piece MakeHuman outfit")
    identity.add_argument("--body", default=None, help=BODY_HELP)
    identity.add_argument("--material", default=None,
                          help="cloth as k=v pairs, as simulate --material (default: HOOD's)")
    identity.add_argument("--checkpoint", default=None, help="HyperBones checkpoint (default: the shipped one)")
    identity.add_argument("--untrained", action="store_true",
                          help="freshly initialised networks instead of a checkpoint (for timing only)")
    identity.add_argument("--uv-resolution", type=int, default=None, help="UV size R (default: the model's)")
    identity.add_argument("--out", required=True, help="output .pt")
    identity.set_defaults(func=cmd_identity)

    bench_rt = sub.add_parser("bench-runtime", help="ms per frame of the per-frame runtime on saved identity caches",
                              description="Times Simulator.step (Module A) on identity caches (Identity.save) over a "
                                          "motion .npz (hyperbones motion NAME --out FILE), BATCH characters at once; "
                                          "needs neither the body model nor the teacher. Prints a table; --json writes "
                                          "the records.")
    bench_rt.add_argument("--identity", action="append", required=True, help="an identity cache (repeatable)")
    bench_rt.add_argument("--motion", required=True, help="motion .npz from `hyperbones motion`")
    bench_rt.add_argument("--checkpoint", default=None, help="HyperBones checkpoint (default: untrained weights)")
    bench_rt.add_argument("--uv-resolution", type=int, default=None, help="UV size R (default: the cache's)")
    bench_rt.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    bench_rt.add_argument("--batch", type=int, default=1, help="characters stepped together (default 1)")
    bench_rt.add_argument("--frames", type=int, default=60, help="timed frames (default 60)")
    bench_rt.add_argument("--warmup", type=int, default=10, help="untimed frames first (default 10)")
    bench_rt.add_argument("--late", type=int, default=None,
                          help="also time the --frames frames from this frame on (e.g. 1000), to show that the cost "
                            "per frame does not grow with the motion's length")
    bench_rt.add_argument("--json", default=None, help="also write the records to this JSON file")
    bench_rt.set_defaults(func=cmd_bench_runtime)

    check_teacher = sub.add_parser("check-teacher", help="tables of long-rollout stability and settling of a learnt method",
                                   description="Rolls the method out for --frames frames on each motion (held still "
                                               "after it ends) and reports NaN, top speed and kinetic energy; then "
                                               "measures how the garment's kinetic energy decays after a clip stops.")
    check_teacher.add_argument("--method", default="teacher", help="learnt method (default: teacher)")
    check_teacher.add_argument("--checkpoint", default=None, help="checkpoint (default: the shipped one)")
    check_teacher.add_argument("--garments", default="tshirt,tshirt-open,pants,long-skirt,dress,tight-dress",
                               help="comma list (default: the six templates)")
    check_teacher.add_argument("--motions", default="walk", help="comma list of motions for the long rollouts")
    check_teacher.add_argument("--frames", type=int, default=1000, help="rollout length (default 1000)")
    check_teacher.add_argument("--settle-motion", default="walk", help="clip before the still hold (default: walk)")
    check_teacher.add_argument("--hold", type=float, default=3.0, help="seconds of stillness after it (default 3)")
    check_teacher.add_argument("--vertices", type=int, default=None, help="template resolution (default 5000)")
    check_teacher.add_argument("--body", default=None, help=BODY_HELP)
    check_teacher.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    _add_source_fps_pairs(check_teacher)
    check_teacher.add_argument("--quiet", action="store_true", help="no progress bars")
    check_teacher.set_defaults(func=cmd_check_teacher)

    check_hem = sub.add_parser("check-hem", help="does the hem keep swinging after the body stops? table + PNG",
                               description="Simulates the garment through the motion and a hold with each method, "
                                           "then reports how long the hem (lowest 5 %% of the garment) keeps moving "
                                           "after the body stops and plots its displacement to --out.")
    check_hem.add_argument("--methods", default="lbs,teacher,hyperbones", help="comma list (default: all three)")
    check_hem.add_argument("--garment", default="dress", help="garment (default: dress)")
    check_hem.add_argument("--motion", default="walk", help="clip that ends with the stop (default: walk)")
    check_hem.add_argument("--hold", type=float, default=2.0, help="seconds of stillness after it (default 2)")
    check_hem.add_argument("--vertices", type=int, default=None, help="template resolution (default 5000)")
    check_hem.add_argument("--body", default=None, help=BODY_HELP)
    check_hem.add_argument("--checkpoint", default=None, help="checkpoint for the learnt methods (default: shipped)")
    check_hem.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    check_hem.add_argument("--out", default="hem.png", help="PNG to write (default: hem.png)")
    _add_source_fps_pairs(check_hem)
    check_hem.add_argument("--runtime", default=None, metavar="KEY=VALUE,...", help=RUNTIME_HELP)
    check_hem.set_defaults(func=cmd_check_hem)

    garment = sub.add_parser("garment", help="make the built-in garments")
    garment_sub = garment.add_subparsers(dest="garment_command", metavar="ACTION", required=True)
    make = garment_sub.add_parser("make", help="a template fitted (and draped) on a body, written as OBJ")
    make.add_argument("type", help="tshirt, tshirt-open, pants, long-skirt, dress or tight-dress")
    make.add_argument("--body", default=None, help=BODY_HELP)
    make.add_argument("--vertices", type=int, default=5000, help="about this many vertices (1000-40000, default 5000)")
    make.add_argument("--out", required=True, help="output .obj")
    make.add_argument("--no-drape", action="store_true", help="write the fitted template without draping it")
    make.set_defaults(func=cmd_garment_make)

    check_drape = sub.add_parser("check-drape", help="table of drape quality over garments, resolutions and bodies")
    check_drape.add_argument("mhclo", nargs="*", help="MakeHuman .mhclo garments to include (every piece)")
    check_drape.add_argument("--resolutions", default="2500,5000,10000",
                             help="template vertex counts (comma list; empty: no templates)")
    check_drape.add_argument("--templates", default="tshirt,tshirt-open,pants,long-skirt,dress,tight-dress",
                             help="procedural templates to include (comma list; empty: none)")
    check_drape.add_argument("--bodies", default="gender=0,weight=0,height=0;gender=1,muscle=1,weight=1,height=1;"
                             "gender=1,weight=0,height=0,proportions=1", help="body shapes separated by ';'")
    check_drape.add_argument("--quiet", action="store_true", help="no progress bar")
    check_drape.set_defaults(func=cmd_check_drape)

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
