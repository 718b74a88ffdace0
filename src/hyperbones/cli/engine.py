"""``hyperbones export-onnx``: the per-frame runtime for a game engine."""

from __future__ import annotations

from hyperbones.cli import options


def run_export_onnx(args) -> int:
    from hyperbones.jobs.export_onnx import export_onnx

    paths = export_onnx(args.garment, args.out, body=args.body, material=args.material, vertices=args.vertices,
                        piece=args.piece, checkpoint=args.checkpoint)
    for kind, path in paths.items():
        print(f"  {kind:8s} {path}")
    return 0


def add_export_onnx(sub) -> None:
    export = sub.add_parser(
        "export-onnx", help="the per-frame runtime of one garment on one body as an ONNX graph, for game engines",
        description="Writes DIR/runtime.onnx (opset 18, one file: Module B's encoding of the garment on the body, "
                    "Module A and the follow, float32), DIR/contract.json (each input and output, units, axes, "
                    "frame rate, the runtime settings) and DIR/garment.obj (the rest mesh with UVs, whose vertex "
                    "order the output follows). Body contact is not in the graph: the engine pushes the garment "
                    "out of its body (README, 'Running the runtime in an engine').")
    options.add_garment(export)
    options.add_body(export)
    options.add_material(export)
    options.add_vertices(export)
    export.add_argument("--piece", type=int, default=None, help="which piece of a multi-piece .mhclo outfit")
    options.add_checkpoint(export)
    options.add_out(export, "output folder")
    export.set_defaults(func=run_export_onnx)


VERBS = (add_export_onnx,)
