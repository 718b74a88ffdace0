"""``hyperbones simulate``: body + motion + garment -> a method's garment motion -> exports.

Output contract (DIR): frames.npz, garment.pc2, scene.usd, preview.mp4 (+ sheet) and
metrics.json. Later methods plug in through METHODS.
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from hyperbones.body.anny_body import body_for
from hyperbones.body.shape import BodyShape
from hyperbones.errors import ParameterError
from hyperbones.export import SceneMesh, write_frames_npz, write_gltf, write_obj_sequence, write_pc2, write_usd
from hyperbones.garment.draped import draped_garment
from hyperbones.garment.garment import Garment
from hyperbones.geometry.boundary import lowest_loop
from hyperbones.io_utils import atomic_path, staged_outputs
from hyperbones.jobs.methods import METHODS
from hyperbones.motion.load import DEFAULT_BLEND_IN, load_motion
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.material import Material
from hyperbones.physics.sequence_metrics import runaway_problem, sequence_metrics
from hyperbones.runtime.config import parse_overrides

GARMENT_COLOR = (0.25, 0.45, 0.8)
GARMENT_DEPTH_OFFSET = 0.003  # m: the preview draws cloth on the skin over it (viz.preview.MeshSequence)


@dataclass
class SimulationResult:
    """A simulated sequence and everything needed to export and score it."""

    garment: Garment                # the draped canonical garment (topology, UVs)
    garment_vertices: torch.Tensor  # (T,V,3)
    body_vertices: torch.Tensor     # (T,Vb,3)
    body_faces: torch.Tensor
    joint_positions: torch.Tensor   # (T,31,3)
    fps: float
    metrics: dict
    vertex_masses: torch.Tensor | None = None  # (V,) kg, lumped from the rest shape


def run_simulation(method: str, garment: str, motion: str, body: str | None = None, *, frames: int | None = None,
                   vertices: int | None = None, piece: int | None = None, material: str | Material | None = None,
                   blend_in: int = DEFAULT_BLEND_IN, hold: float = 0.0, checkpoint: str | None = None, device: str = "auto",
                   source_fps: float | None = None, progress: bool = False,
                   uv_resolution: int | None = None, runtime: str | dict | None = None,
                   report: Callable[[str, float], None] | None = None) -> SimulationResult:
    """Simulate ``garment`` on ``body`` through ``motion`` with ``method``; compute all metrics.

    ``checkpoint`` (learnt methods; default: the shipped model) and ``device`` ("auto":
    CUDA when present) apply to the learnt methods; LBS ignores them. ``source_fps`` is the
    real capture rate of a BVH clip whose header is wrong. ``material``: a ``Material`` or
    ``--material`` text (None: the default cloth). ``uv_resolution``: the UV maps'
    R for the hyperbones methods (default: the model's training one); ``runtime``: settings
    (``--runtime`` text or a dict) over the checkpoint's ``RuntimeConfig``. The metrics record
    the runtime settings used (``runtime``; None for methods without the runtime).
    ``report(stage, fraction)``, when given, hears what is being done and how much of the
    run is done (a viewer's progress bar).
    """
    report = report or _silent
    if method not in METHODS:
        raise ParameterError(f"unknown method {method!r}; available: {', '.join(METHODS)}")
    if frames is not None and frames < 1:
        raise ParameterError(f"--frames must be >= 1, got {frames}")
    overrides = parse_overrides(runtime)
    shape = BodyShape.parse(body)
    cloth = material if isinstance(material, Material) else Material.parse(material)
    report("making the body", 0.0)
    the_body = body_for(shape)
    report("retargeting the motion", 0.05)
    the_motion = load_motion(motion, the_body, blend_in=blend_in, hold=hold, source_fps=source_fps)
    if frames is not None:
        the_motion = the_motion.slice(0, frames)
    report("draping the garment on the body", 0.1)
    draped, rest_vertices = draped_garment(garment, the_body, vertices=vertices, piece=piece, material=cloth)
    report("posing the body", 0.3)
    posed = the_body.pose(the_motion.joint_rotations, the_motion.root_translation)
    report(f"encoding the garment and body ({method})", 0.35)
    extra = {"uv_resolution": uv_resolution, "runtime": overrides} if method.startswith("hyperbones") else {}
    solver = METHODS[method](draped, the_body, rest_vertices=rest_vertices, material=cloth, checkpoint=checkpoint,
                             device=device, progress=progress, **extra)
    garment_vertices, frame_ms = _timed_frames(solver, posed, method, progress,
                                               lambda done, total: report(f"simulating frame {done}/{total}",
                                                                          0.4 + 0.55 * done / total))
    report("measuring the garment", 0.95)
    rest = ClothRest.from_mesh(rest_vertices.double(), draped.faces, cloth)
    metrics = sequence_metrics(garment_vertices, rest, posed.vertices, the_body.faces,
                               origin=posed.joint_positions[0, 0], dt=1.0 / the_motion.fps,
                               drape=(draped.vertices, the_body.rest_vertices),
                               hem=lowest_loop(draped.faces, draped.vertices))
    metrics.update({"frames": the_motion.num_frames, "ms_per_frame": float(frame_ms.mean()),
                    "ms_median": float(frame_ms.median()), "ms_p95": float(torch.quantile(frame_ms, 0.95)),
                    "method": method, "garment": garment if Path(garment).suffix == "" else Path(garment).name,
                    "garment_vertices": draped.num_vertices, "motion": the_motion.name, "body": shape.label(),
                    "fps": the_motion.fps, "runtime": _runtime_record(solver),
                    "conv_mlp_dtype": _conv_mlp_dtype(solver)})
    problem = runaway_problem(metrics)
    if problem:
        warnings.warn(f"{method} on {metrics['garment']}, {metrics['motion']}: {problem}; its metrics mean little",
                      stacklevel=2)
    return SimulationResult(draped, garment_vertices, posed.vertices, the_body.faces,
                            posed.joint_positions, the_motion.fps, metrics, rest.vertex_masses.float())


def _silent(stage: str, fraction: float) -> None:
    """A ``report`` that tells no one."""


def _timed_frames(solver, posed, method: str, progress: bool,
                  on_frame: Callable[[int, int], None] = lambda done, total: None) -> tuple[torch.Tensor, torch.Tensor]:
    """Step ``solver`` through ``posed`` frame by frame: (T,V,3) garment positions on the CPU and
    (T,) milliseconds each frame took (CUDA work finished before the clock is read), so a run
    reports the spread of its frame times (median, 95th percentile), not only their mean.
    ``on_frame(done, total)`` hears of each finished frame."""
    positions, times = [], []
    frames = solver.frames(posed)
    device = getattr(solver, "device", None)
    total = posed.joint_rotations.shape[0]
    for done in tqdm(range(1, total + 1), desc=method, disable=not progress, unit="frame"):
        start = time.perf_counter()
        frame = next(frames)
        if isinstance(device, torch.device) and device.type == "cuda":
            torch.cuda.synchronize(device)
        times.append(1000.0 * (time.perf_counter() - start))
        positions.append(frame.cpu())
        on_frame(done, total)
    return torch.stack(positions), torch.tensor(times, dtype=torch.float64)


def _runtime_record(solver) -> dict | None:
    """The runtime settings a method ran with (None for methods without the runtime)."""
    config = getattr(solver, "runtime_config", None)
    return None if config is None else config.as_dict()


def _conv_mlp_dtype(solver) -> str | None:
    """The dtype Module A's Conv-MLP ran in ("float32" or "bfloat16": ``RuntimeConfig.bfloat16``
    where the device runs it natively); None for methods without the runtime."""
    simulator = getattr(solver, "simulator", None)
    dtype = getattr(simulator, "conv_mlp_dtype", None)
    return None if dtype is None else str(dtype).removeprefix("torch.")


def export_simulation(result: SimulationResult, out_dir: str | Path, preview: bool = True, obj: bool = False,
                      progress: bool = True, gltf: bool = False) -> dict[str, Path]:
    """Write the output contract into ``out_dir`` (and, with ``obj``, an OBJ per frame into
    ``out_dir/obj``; with ``gltf``, body and garment animated in ``out_dir/scene.glb``);
    returns the written paths by kind. All or nothing (``staged_outputs``): when one file
    cannot be written, none of the set replaces an earlier run's."""
    from hyperbones.viz.scene import BODY_COLOR

    garment = result.garment
    out = Path(out_dir)
    meshes = [SceneMesh("body", result.body_vertices.numpy(), result.body_faces.numpy(), display_color=BODY_COLOR),
              SceneMesh("garment", result.garment_vertices.numpy(), garment.faces.numpy(),
                        uvs=garment.uvs.numpy(), face_uvs=garment.face_uvs.numpy(), display_color=GARMENT_COLOR)]
    with staged_outputs(out) as staging:
        names = {
            "frames": write_frames_npz(staging / "frames.npz", garment_vertices=result.garment_vertices,
                                       garment_faces=garment.faces, body_vertices=result.body_vertices,
                                       body_faces=result.body_faces, joint_positions=result.joint_positions,
                                       fps=result.fps).name,
            "pc2": write_pc2(staging / "garment.pc2", result.garment_vertices.numpy(), fps=result.fps).name,
            "usd": write_usd(staging / "scene.usd", meshes, fps=result.fps).name,
        }
        if gltf:
            names["gltf"] = write_gltf(staging / "scene.glb", meshes, fps=result.fps).name
        if preview:
            from hyperbones.viz.preview import MeshSequence, render_preview

            m = result.metrics
            title = f"{m['method']} | {m['garment']} | {m['motion']} | body {m['body']}"
            video, sheet = render_preview(
                [MeshSequence(result.body_vertices.numpy(), result.body_faces.numpy(), BODY_COLOR, "body"),
                 MeshSequence(result.garment_vertices.numpy(), garment.faces.numpy(), GARMENT_COLOR, "garment",
                              depth_offset=GARMENT_DEPTH_OFFSET)],
                staging / "preview.mp4", result.fps, title=title, progress=progress)
            names.update(preview=video.name, sheet=sheet.name)
        if obj:
            write_obj_sequence(staging / "obj", result.garment_vertices.numpy(), garment.faces.numpy(),
                               uvs=garment.uvs.numpy(), face_uvs=garment.face_uvs.numpy())
            names["obj"] = "obj"
        with atomic_path(staging / "metrics.json") as tmp:
            tmp.write_text(json.dumps(result.metrics, indent=2) + "\n")
        names["metrics"] = "metrics.json"
    return {kind: out / name for kind, name in names.items()}


