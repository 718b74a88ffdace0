"""Verbs that simulate or time garments: demo, simulate, eval, bench, identity, bench-runtime."""

from __future__ import annotations

import time
from pathlib import Path

from hyperbones.cli import options
from hyperbones.errors import ParameterError

DEMO_VERTICES = 2500  # the dress at the shipped model's larger training resolution


def _print_run(result, paths: dict) -> None:
    """One line of what a simulation measured, then where its outputs are."""
    m = result.metrics
    print(f"{m['method']} on {m['garment']} ({m['garment_vertices']} vertices), {m['motion']} ({m['frames']} frames): "
          f"{m['ms_per_frame']:.2f} ms/frame, edge error {m['edge_error_pct']:.2f} %, "
          f"collision {m['collision_pct']:.2f} %")
    for kind, path in paths.items():
        print(f"  {kind:8s} {Path(path).resolve()}")


def run_demo(args) -> int:
    from hyperbones.jobs.simulate import export_simulation, run_simulation

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


def add_demo(sub) -> None:
    demo = sub.add_parser("demo", help="simulate the default dress with the shipped model and write every output",
                          description=f"The default dress ({DEMO_VERTICES:,} vertices) on the default Anny body "
                                      "walking, then still for 1 s, simulated by the shipped HyperBones model. Writes "
                                      "preview.mp4 + preview_sheet.png, scene.usd, garment.pc2, frames.npz and "
                                      "metrics.json into --out and prints their paths.")
    options.add_out(demo, "output folder", default="hyperbones-demo")
    options.add_device(demo)
    options.add_runtime(demo)
    options.add_quiet(demo)
    demo.set_defaults(func=run_demo)


def run_simulate(args) -> int:
    from hyperbones.jobs.simulate import export_simulation, run_simulation

    result = run_simulation(args.method, args.garment, args.motion, args.body, frames=args.frames,
                            vertices=args.vertices, piece=args.piece, material=args.material,
                            blend_in=args.blend_in, hold=args.hold, checkpoint=args.checkpoint, device=args.device,
                            source_fps=args.source_fps, progress=not args.quiet, runtime=args.runtime,
                            uv_resolution=args.uv_resolution)
    paths = export_simulation(result, args.out, preview=not args.no_preview, obj=args.obj, progress=not args.quiet,
                              gltf=args.gltf)
    _print_run(result, paths)
    return 0


METHOD_HELP = ("hyperbones: the shipped model's per-frame runtime (the garment follows Module A's output, is "
               "pushed out of the body and has its edges pulled back to length each frame); hyperbones-raw: "
               "Module A alone; hyperbones-onnx: the runtime exported to ONNX (export-onnx) run by onnxruntime, "
               "without body contact; lbs: skinning, no dynamics; teacher: the physics-trained MeshGraphNet; physics: "
               "each frame's energy minimised by L-BFGS (slow, the teacher's reference)")


def add_simulate(sub) -> None:
    simulate = sub.add_parser("simulate", help="simulate a garment on a moving body and export it",
                              description="Writes DIR/frames.npz, garment.pc2, scene.usd, preview.mp4 and "
                                          f"metrics.json. Methods: {METHOD_HELP}.")
    simulate.add_argument("--method", default="hyperbones",
                          help=f"one of {', '.join(options.method_names())} (default: hyperbones)")
    options.add_checkpoint(simulate)
    options.add_device(simulate)
    options.add_garment(simulate)
    simulate.add_argument("--motion", default="walk", help="a built-in motion or a CMU .bvh file (default: walk)")
    options.add_body(simulate)
    options.add_out(simulate, "output folder")
    simulate.add_argument("--frames", type=int, default=None, help="simulate only the first N frames")
    options.add_vertices(simulate)
    simulate.add_argument("--piece", type=int, default=None, help="which piece of a multi-piece .mhclo outfit")
    options.add_material(simulate)
    options.add_blend_in(simulate)
    options.add_hold(simulate)
    options.add_source_fps(simulate)
    options.add_uv_resolution(simulate)
    options.add_runtime(simulate)
    simulate.add_argument("--obj", action="store_true", help="also write an OBJ per frame into DIR/obj/")
    simulate.add_argument("--gltf", action="store_true",
                          help="also write DIR/scene.glb: body and garment as binary glTF 2.0 (Y up, metres), one "
                               "morph target a frame and one weight animation, as three.js, Blender and Babylon.js "
                               "import vertex animation")
    simulate.add_argument("--no-preview", action="store_true", help="skip the preview video")
    options.add_quiet(simulate)
    simulate.set_defaults(func=run_simulate)


def run_eval(args) -> int:
    from hyperbones.jobs.evaluate import evaluate, split_set

    source_fps = options.source_fps_pairs(args)
    if args.split:
        if args.motions or args.bodies:
            raise ParameterError("--split sets the motions and bodies: leave out --motions and --bodies")
        data = None
        if args.config:
            from hyperbones.training.config import load_config

            data = load_config(args.config).data
        motions, bodies, rates = split_set(args.split, data)
        source_fps = {**rates, **source_fps}
    else:
        motions = options.comma_list(args.motions or "walk,run")
        bodies = [b.strip() for b in args.bodies.split(";")] if args.bodies else [None]
    report = evaluate(options.comma_list(args.methods), options.comma_list(args.garments), motions, bodies, args.out,
                      frames=args.frames, vertices=args.vertices, hold=args.hold, checkpoint=args.checkpoint,
                      device=args.device, source_fps=source_fps, progress=not args.quiet,
                      uv_resolution=args.uv_resolution, runtime=args.runtime)
    print(report.read_text())
    print(f"wrote {report.resolve()} and {report.with_suffix('.json').resolve()}")
    return 0


def add_eval(sub) -> None:
    evaluation = sub.add_parser("eval", help="evaluate methods over garments, motions and bodies",
                                description="Writes DIR/report.md (a methods x garments table of means) and "
                                            "DIR/report.json (every run's metrics and settings).")
    options.add_methods(evaluation, default="lbs")
    options.add_checkpoint(evaluation)
    options.add_device(evaluation)
    options.add_hold(evaluation)
    options.add_garments(evaluation, default="tshirt,dress,long-skirt,pants")
    evaluation.add_argument("--motions", default=None,
                            help="comma list of motions, built-in names or .bvh files (default: walk,run)")
    evaluation.add_argument("--bodies", default=None, help="body shapes separated by ';' (default: the default body)")
    evaluation.add_argument("--split", default=None, choices=("validation", "test"),
                            help="the training config's data split instead of --motions and --bodies: validation "
                                 "(data.validation_clips x validation_bodies) chooses settings, test (test_clips x "
                                 "test_bodies) only reports (docs/validation.md)")
    evaluation.add_argument("--config", default=None,
                            help="training config whose [data] gives --split's clips and bodies (default: the "
                                 "defaults in hyperbones.training.config)")
    evaluation.add_argument("--frames", type=int, default=None, help="only the first N frames of each motion")
    options.add_vertices(evaluation)
    options.add_out(evaluation, "output folder")
    options.add_uv_resolution(evaluation)
    options.add_runtime(evaluation)
    options.add_source_fps_pairs(evaluation)
    options.add_quiet(evaluation)
    evaluation.set_defaults(func=run_eval)


def _report_records(records, json_path: str | None, notes: list[str], after: list[str] | None = None) -> None:
    """Print bench records as a table, then ``notes``, then each block of ``after`` (a blank
    line before each); write the records to ``json_path`` when given."""
    import json

    from hyperbones.io_utils import atomic_path
    from hyperbones.jobs.timing import bench_table, records_as_dicts

    print(bench_table(records))
    for line in notes:
        print(line)
    for block in after or []:
        print()
        print(block)
    if json_path:
        with atomic_path(json_path) as tmp:
            tmp.write_text(json.dumps(records_as_dicts(records), indent=2) + "\n")
        print(f"wrote {Path(json_path).resolve()}")


def _add_timing(parser, frames: int, warmup: int) -> None:
    parser.add_argument("--frames", type=int, default=frames, help=f"timed frames per run (default: {frames})")
    parser.add_argument("--warmup", type=int, default=warmup, help=f"untimed frames first (default: {warmup})")
    parser.add_argument("--late", type=int, default=None,
                        help="also time the --frames frames from this frame on (e.g. 1000), to show that the cost "
                             "per frame does not grow with the motion's length")
    parser.add_argument("--json", default=None, help="also write the records to this JSON file")


def run_bench(args) -> int:
    from hyperbones.jobs.bench import bench
    from hyperbones.jobs.timing import speedups, stage_table

    records = bench(options.comma_list(args.methods), options.comma_list(args.garments), vertices=args.vertices,
                    device=args.device, frames=args.frames, warmup=args.warmup, late=args.late,
                    checkpoint=args.checkpoint, uv_resolution=args.uv_resolution, progress=not args.quiet,
                    runtime=args.runtime, batch=args.batch, profile=args.profile)
    notes = speedups(records)
    profiled = [record for record in records if record.stages]
    if args.profile:
        unprofiled = sorted({record.method for record in records} - {record.method for record in profiled})
        if unprofiled:
            notes.append(f"(--profile: no stage table for {', '.join(unprofiled)}, which have no per-frame runtime)")
    _report_records(records, args.json, notes, [stage_table(record) for record in profiled])
    return 0


CROWD_HELP = ("time a crowd of N characters stepped together by one Simulator (hyperbones and hyperbones-raw only) "
              "instead of each garment alone: the characters cycle through --garments and 4 body shapes (each "
              "garment x body draped and encoded once), each walking its own retargeted walk; the record, garment "
              "'crowd of N (...)', holds ms per character-frame, i.e. frame time / N (default: 1)")
"""--batch's help (bench.CROWD_METHODS and CROWD_BODIES, written out: importing bench would cost
--help seconds of torch)."""


def add_bench(sub) -> None:
    bench = sub.add_parser("bench", help="ms per frame (median and 95th percentile) of each method on each garment",
                           description="Times each method frame by frame on the default body walking, after a warm-up "
                                       "(CUDA timings synchronised): prints the median and the 95th percentile of the "
                                       "frames' times in a table; --json writes records {method, garment, vertices, "
                                       "device, batch, ms_per_frame (the median), p95_ms, from_frame, stages}.")
    options.add_methods(bench, default="lbs,teacher")
    options.add_garments(bench)
    options.add_vertices(bench)
    options.add_device(bench)
    _add_timing(bench, frames=30, warmup=5)
    bench.add_argument("--profile", action="store_true",
                       help="also time each stage of the per-frame runtime (forward kinematics, Bone-Net, skinning, "
                            "UV stages, follow, contact, projection) over the first timed block and print a table "
                            "per method and garment: ms per frame, share of the median frame, their total; --json "
                            "records them as 'stages' (empty for lbs and teacher, which have no such stages)")
    bench.add_argument("--batch", type=int, default=1, metavar="N", help=CROWD_HELP)
    options.add_checkpoint(bench)
    options.add_uv_resolution(bench)
    options.add_runtime(bench)
    options.add_quiet(bench)
    bench.set_defaults(func=run_bench)


def run_identity(args) -> int:
    import torch

    from hyperbones.body.anny_body import body_for
    from hyperbones.body.shape import BodyShape
    from hyperbones.garment.draped import draped_garment
    from hyperbones.models.loading import hyperbones_from_checkpoint
    from hyperbones.physics.material import Material
    from hyperbones.runtime.identity import encode_identity

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
    if not args.untrained:  # the model's runtime proxy travels in the cache (no pymeshlab needed where it is used)
        from hyperbones.models.loading import hyperbones_payload
        from hyperbones.runtime.simulator import runtime_config_of

        payload = hyperbones_payload(args.checkpoint, "cpu", whole=False)
        identity = identity.with_proxy(runtime_config_of(payload, args.checkpoint or "the shipped model").proxy_vertices)
    out = identity.save(args.out)
    proxy = f", proxy {identity.proxy.num_vertices} vertices" if identity.proxy is not None else ""
    print(f"wrote {out.resolve()} ({identity.num_vertices} vertices, {identity.bones.num_bones} bones, "
          f"UV {identity.raster.resolution}²{proxy}{', untrained: for timing only' if args.untrained else ''})")
    return 0


def add_identity(sub) -> None:
    identity = sub.add_parser("identity", help="encode a body x garment once (Module B) and save the identity cache",
                              description="Drapes the garment on the body, runs Module B and writes the cache the "
                                          "per-frame runtime loads (Identity.load, bench-runtime --identity).")
    options.add_garment(identity)
    options.add_vertices(identity)
    identity.add_argument("--piece", type=int, default=None, help="piece of a multi-piece MakeHuman outfit")
    options.add_body(identity)
    options.add_material(identity)
    options.add_checkpoint(identity, help="HyperBones checkpoint (default: the shipped one)")
    identity.add_argument("--untrained", action="store_true",
                          help="freshly initialised networks instead of a checkpoint (for timing only)")
    options.add_uv_resolution(identity)
    options.add_out(identity, "output .pt")
    identity.set_defaults(func=run_identity)


def run_bench_runtime(args) -> int:
    from hyperbones.jobs.bench_runtime import bench_runtime

    records = bench_runtime(args.identity, args.motion, checkpoint=args.checkpoint, uv_resolution=args.uv_resolution,
                            device=args.device, batch=args.batch, frames=args.frames, warmup=args.warmup,
                            late=args.late, runtime=args.runtime)
    _report_records(records, args.json, [] if args.checkpoint else ["(Module A freshly initialised: timing only)"])
    return 0


def add_bench_runtime(sub) -> None:
    bench_rt = sub.add_parser("bench-runtime",
                              help="ms per frame (median, 95th percentile) of the per-frame runtime on saved identity "
                                   "caches",
                              description="Times Simulator.step (Module A and the follow; no body, so no contact) on "
                                          "identity caches (Identity.save) over a motion .npz (hyperbones motion "
                                          "NAME --out FILE), BATCH characters at once; needs neither the body model "
                                          "nor the teacher. Prints the median and 95th percentile of the frames' "
                                          "times (for the whole batch) in a table; --json writes the records.")
    bench_rt.add_argument("--identity", action="append", required=True, help="an identity cache (repeatable)")
    bench_rt.add_argument("--motion", required=True, help="motion .npz from `hyperbones motion`")
    options.add_checkpoint(bench_rt, help="HyperBones checkpoint (default: untrained weights)")
    bench_rt.add_argument("--uv-resolution", type=int, default=None, help="UV size R (default: the cache's)")
    options.add_device(bench_rt, default="cpu")
    bench_rt.add_argument("--batch", type=int, default=1, help="characters stepped together (default: 1)")
    _add_timing(bench_rt, frames=60, warmup=10)
    options.add_runtime(bench_rt)
    bench_rt.set_defaults(func=run_bench_runtime)


VERBS = (add_demo, add_simulate, add_eval, add_bench, add_identity, add_bench_runtime)
