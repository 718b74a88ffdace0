"""``hyperbones eval``: methods x garments x motions x bodies -> report.md and report.json."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

from tqdm import tqdm

from hyperbones.errors import ParameterError
from hyperbones.io_utils import atomic_path, staged_outputs
from hyperbones.jobs.simulate import run_simulation
from hyperbones.motion.load import capture_rate
from hyperbones.runtime.config import parse_overrides

COLUMNS = [("edge_error_pct", "ε_e %"), ("area_error_pct", "ε_a %"), ("collision_pct", "ε_c % (d<0)"),
           ("collision_1mm_pct", "ε_c % (d<1mm)"), ("detached_pct", "detached %"), ("hem_area_cm2", "hem area cm²"),
           ("strain", "strain J"), ("bending", "bending J"), ("inertia", "inertia J"), ("gravity", "gravity J"),
           ("ms_median", "ms/frame (median)"), ("ms_p95", "ms/frame (p95)")]


SPLITS = ("validation", "test")


def split_set(split: str, data=None) -> tuple[list[str], list[str], dict[str, float]]:
    """The motions (BVH paths), bodies and capture rates of a data split of the training
    config's ``data`` section (default: the defaults): ``validation`` chooses settings,
    ``test`` only reports (docs/validation.md)."""
    from hyperbones.training.config import DataConfig

    data = data or DataConfig()
    if split not in SPLITS:
        raise ParameterError(f"--split must be one of {', '.join(SPLITS)}, got {split!r}")
    clips = data.validation_clips if split == "validation" else data.test_clips
    bodies = data.validation_bodies if split == "validation" else data.test_bodies
    return [str(Path(data.mocap_dir) / f"{clip}.bvh") for clip in clips], list(bodies), dict(data.source_fps)


def evaluate(methods: list[str], garments: list[str], motions: list[str], bodies: list[str], out_dir: str | Path,
             *, frames: int | None = None, vertices: int | None = None, hold: float = 0.0,
             checkpoint: str | None = None, device: str = "auto", source_fps: dict[str, float] | None = None,
             progress: bool = True, uv_resolution: int | None = None, runtime: str | None = None) -> Path:
    """Run every combination, write ``report.json`` (every run) and ``report.md`` (means per
    method and garment over motions and bodies). ``source_fps`` maps a BVH clip's file stem
    to its real capture rate where the header is wrong; ``runtime``: ``--runtime`` settings for
    the hyperbones methods (each run's record keeps the settings it ran with). Returns the
    report.md path."""
    parse_overrides(runtime)  # a bad setting fails before the first run, not after it
    runs = []
    combos = [(m, g, mo, b) for g in garments for b in bodies for mo in motions for m in methods]
    # Staged from the start: a folder that cannot be written fails before the first run, and
    # the two reports appear together or not at all.
    with staged_outputs(out_dir) as staging:
        for method, garment, motion, body in tqdm(combos, desc="eval", disable=not progress):
            result = run_simulation(method, garment, motion, body, frames=frames, vertices=vertices, hold=hold,
                                    checkpoint=checkpoint, device=device, source_fps=capture_rate(motion, source_fps),
                                    uv_resolution=uv_resolution, runtime=runtime)
            runs.append(result.metrics)
        with atomic_path(staging / "report.json") as tmp:
            tmp.write_text(json.dumps(runs, indent=2) + "\n")
        with atomic_path(staging / "report.md") as tmp:
            tmp.write_text(_markdown(runs, motions, bodies))
    return Path(out_dir) / "report.md"


def _markdown(runs: list[dict], motions: list[str], bodies: list[str]) -> str:
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for run in runs:
        groups[(run["garment"], run["method"])].append(run)
    header = "| garment | method | " + " | ".join(label for _, label in COLUMNS) + " |"
    lines = [f"Means over motions ({', '.join(motions)}) and bodies ({'; '.join(b or 'default' for b in bodies)}). "
             "Metrics as REFERENCE.md defines them: GAPS edge/area errors against the canonical template, "
             "collision as % of vertex-frames inside the body, HOOD per-frame energies (frames t >= 2, "
             "gravity measured from the body root at frame 0).", "", header,
             "|---|---|" + "---:|" * len(COLUMNS)]
    for (garment, method), group in groups.items():
        cells = []
        for key, _ in COLUMNS:
            values = [run[key] for run in group if key in run]
            cells.append(f"{sum(values) / len(values):.4g}" if values else "-")
        lines.append(f"| {garment} | {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
