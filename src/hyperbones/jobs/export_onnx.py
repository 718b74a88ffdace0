"""``hyperbones export-onnx``: one character's per-frame runtime (without contact) as an ONNX
graph, its contract, and the garment's rest mesh, for a game engine (README, "Running the
runtime in an engine")."""

from __future__ import annotations

import json
from pathlib import Path

from hyperbones.body.anny_body import body_for
from hyperbones.body.shape import BodyShape
from hyperbones.garment.draped import draped_garment
from hyperbones.garment.garment import Garment
from hyperbones.garment.obj_io import write_obj_garment
from hyperbones.io_utils import atomic_path, staged_outputs
from hyperbones.physics.material import Material
from hyperbones.runtime.onnx_frame import ONNX_OVERRIDES, OPSET, OUTPUTS, RuntimeFrame, write_onnx
from hyperbones.runtime.simulator import Simulator

def runtime_frame(garment: str, body: str | None = None, material: str | None = None, vertices: int | None = None,
                  piece: int | None = None, checkpoint: str | None = None) -> tuple[RuntimeFrame, Garment]:
    """The ``RuntimeFrame`` of ``garment`` draped on ``body`` (Module B encodes it once with the
    model of ``checkpoint``, default the shipped one), and the draped garment."""
    the_body = body_for(BodyShape.parse(body))
    cloth = Material.parse(material)
    draped, rest = draped_garment(garment, the_body, vertices=vertices, piece=piece, material=cloth)
    simulator = Simulator.load([(draped, the_body)], checkpoint, "cpu", overrides=ONNX_OVERRIDES,
                               rest_vertices=[rest])
    return RuntimeFrame(simulator).eval(), draped


def contract(frame: RuntimeFrame, draped: Garment) -> dict:
    """What an engine needs to call the graph: each input and output, shape and meaning."""
    k, b, v = frame.window_frames, frame.num_bones, frame.num_vertices
    state = "state carried from the last call's outputs (the first call: zeros, identities and frame 0)"
    inputs = {
        "joint_rotations": {"shape": [31, 3, 3], "meaning": "each CMU joint's world rotation relative to the "
                            "A-pose, row-major 3x3, in the order of hyperbones.body.skeleton.JOINT_NAMES"},
        "root_translation": {"shape": [3], "meaning": "the Hips joint's world position, metres"},
        "bone_window": {"shape": [k, b, 3], "meaning": f"{state}: the virtual bones' last {k} positions"},
        "last_vertices": {"shape": [v, 3], "meaning": f"{state}: the last output vertices"},
        "last_to_local": {"shape": [4, 4], "meaning": f"{state}: the last heading frame"},
        "last_motion": {"shape": [4, 4], "meaning": f"{state}: the last heading motion"},
        "frame": {"shape": [1], "meaning": "frames stepped so far (0 on the first call)"},
    }
    return {
        "opset": OPSET, "frame_rate": 30.0, "units": "metres", "axes": "Z up, the body faces -Y (the A-pose)",
        "garment": {"vertices": v, "faces": int(draped.faces.shape[0]), "mesh": "garment.obj (rest shape, UVs)"},
        "runtime": frame.config.as_dict(),
        "inputs": inputs,
        "outputs": {
            "vertices": {"shape": [v, 3], "meaning": "the garment's world vertices at this frame, metres"},
            **{name: {"shape": inputs[name.removeprefix("next_")]["shape"],
                      "meaning": f"the next call's {name.removeprefix('next_')}"} for name in OUTPUTS[1:]},
        },
        "not_in_the_graph": "body contact: push vertices inside the body (or within contact_margin of it) out "
                            "along the nearest body face's normal, then pull edges back towards rest length",
    }


def export_onnx(garment: str, out_dir: str | Path, body: str | None = None, material: str | None = None,
                vertices: int | None = None, piece: int | None = None,
                checkpoint: str | None = None) -> dict[str, Path]:
    """Write ``runtime.onnx``, ``contract.json`` and ``garment.obj`` into ``out_dir`` (all or none)."""
    frame, draped = runtime_frame(garment, body, material, vertices, piece, checkpoint)
    out = Path(out_dir)
    with staged_outputs(out) as staging:
        write_onnx(frame, staging / "runtime.onnx")
        with atomic_path(staging / "contract.json") as tmp:
            tmp.write_text(json.dumps(contract(frame, draped), indent=2) + "\n")
        write_obj_garment(staging / "garment.obj", draped)
    return {"onnx": out / "runtime.onnx", "contract": out / "contract.json", "mesh": out / "garment.obj"}
