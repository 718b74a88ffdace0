"""The runtime's benchmark for a GPU machine: prepared here, run there with torch alone.

The project's GPU machines have Python with torch, numpy and scipy but neither Anny, Warp
nor the drape, and take at most 64 MiB with them. ``prepare`` (here, where those are) writes
what the per-frame runtime needs into one folder: the dress's identity caches at 2.5k, 5k and
8k vertices on the default body, the body's skinning rig, the walk's joint rotations, and a
copy of ``roma`` (pure Python, missing there). ``run`` (there, or here with ``--cpu``) times
Module A alone at several UV resolutions and the whole runtime (follow, contact with the torch
search, edge projection with the dense solver on a GPU), batches of characters, float32 and
bfloat16, and prints one table, rewritten after every row. A row's frames are fewer where its
first frame is slow, and no row starts after 4 minutes: the first GPU call ran the 2.5k rows
alone for 3 minutes (docs/experiments/2026-11-28-first-gpu-training-call.md).
``scripts/device/bench.sh`` wraps both.

    python -m hyperbones.jobs.device_bench prepare --out .device/bench
    python -m hyperbones.jobs.device_bench run --folder .device/bench [--device cpu] [--quick]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from hyperbones.io_utils import atomic_path

VERTICES = (2500, 5000, 8000)
RESOLUTIONS = (64, 128, 512)  # 512: the paper's
BATCHES = (1, 64, 1024)
RUNTIME_BATCHES = (1, 8)  # contact and projection still loop over characters
GARMENT = "dress"
ROW_SECONDS = 3.0  # the most a row's timed frames should take (its first frame says how many fit)
JOB_SECONDS = 240.0  # no row starts after this: the issue gives the job 5 minutes on the GPU machine


@dataclass
class DeviceRow:
    """One timing: what ran, on how many characters, and the median ms per frame and per character-frame."""

    garment: str
    vertices: int
    what: str
    batch: int
    dtype: str
    ms_per_frame: float | None  # None: not timed (``missing`` says why)
    ms_per_character: float | None
    missing: str = "out of memory"


def prepare(out: str | Path, vertices: tuple[int, ...] = VERTICES, garment: str = GARMENT) -> list[Path]:
    """Write the benchmark's inputs into ``out`` (needs Anny and Warp); returns the files written."""
    from hyperbones.body.anny_body import body_for
    from hyperbones.body.rig import BodyRig
    from hyperbones.body.shape import BodyShape
    from hyperbones.garment.draped import draped_garment
    from hyperbones.models.loading import hyperbones_from_checkpoint, hyperbones_payload
    from hyperbones.motion.load import load_motion
    from hyperbones.runtime.identity import encode_identity
    from hyperbones.runtime.simulator import runtime_config_of

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    body = body_for(BodyShape())
    model = hyperbones_from_checkpoint(None, "cpu")
    # The GPU machine lacks pymeshlab: the shipped runtime's proxy travels in the cache.
    proxy_vertices = runtime_config_of(hyperbones_payload(None, "cpu", whole=False)).proxy_vertices
    written = []
    for count in vertices:
        draped, rest = draped_garment(garment, body, vertices=count)
        with torch.no_grad():
            identity = encode_identity(model, draped, body, name=f"{garment}-{count}", rest_vertices=rest)
        identity = identity.with_proxy(proxy_vertices)
        written.append(identity.save(out / f"{garment}-{count}.identity.pt"))
    written.append(BodyRig.of(body).save(out / "body.rig.pt"))
    motion = load_motion("walk", body)
    roots = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=False).joint_positions[:, 0]
    torch.save({"rotations": motion.joint_rotations.float(), "roots": roots.float()}, out / "walk.pt")
    written.append(out / "walk.pt")
    written.append(copy_package("roma", out / "site"))
    return written


def copy_package(name: str, site: str | Path) -> Path:
    """Copy the installed pure-Python package ``name`` into folder ``site`` (put on PYTHONPATH
    there), for a machine that lacks it (roma, on the GPU machines); returns its copy."""
    import importlib.util

    copy = Path(site) / name
    source = Path(importlib.util.find_spec(name).submodule_search_locations[0])
    if source.resolve() != copy.resolve():  # a second --prepare finds the first one's copy on PYTHONPATH
        shutil.copytree(source, copy, dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__"))
    return copy


def runtime_label(config) -> str:
    """The table's name for the full runtime's rows under ``config`` (a ``RuntimeConfig``)."""
    return f"runtime @ {config.uv_resolution or 'model'}²" if config.conv_mlp else "runtime (no Conv-MLP)"


def run(folder: str | Path, device: str = "cuda", quick: bool = False, frames: int = 30,
        warmup: int = 10, on_row: Callable[[list[DeviceRow]], None] | None = None,
        row_seconds: float = ROW_SECONDS, seconds: float = JOB_SECONDS) -> list[DeviceRow]:
    """Time every prepared identity (largest last); ``quick``: the smallest one only, 64², batches
    1 and 2, float32, a few frames (the suite's check that the job runs). ``on_row`` gets the
    rows so far after each one (so a call cut short still returns what it measured).

    Each row times up to ``frames`` frames after up to ``warmup``, fewer where its first frame
    says they would take more than ``row_seconds`` (at least 3 and 1); rows that would start
    after ``seconds`` are listed as not timed, so the job ends in a known time."""
    from hyperbones.body.rig import BodyRig
    from hyperbones.models.loading import hyperbones_payload, load_module_a
    from hyperbones.runtime.config import RAW, RuntimeConfig
    from hyperbones.runtime.identity import Identity
    from hyperbones.runtime.simulator import Simulator, runtime_config_of

    folder = Path(folder)
    the_device = torch.device(device)
    paths = sorted(folder.glob("*.identity.pt"), key=lambda p: Identity.load(p).num_vertices)
    if not paths:
        raise FileNotFoundError(f"{folder}: no *.identity.pt (run `prepare` first)")
    rig = BodyRig.load(folder / "body.rig.pt", the_device)
    walk = torch.load(folder / "walk.pt")
    rotations, roots = walk["rotations"].to(the_device), walk["roots"].to(the_device)
    shipped = runtime_config_of(hyperbones_payload(None, "cpu", whole=False))
    module_a = load_module_a(None, the_device)
    resolutions, batches, runtime_batches = RESOLUTIONS, BATCHES, RUNTIME_BATCHES
    dtypes = (False, True)
    if quick:
        paths, resolutions, batches, runtime_batches, dtypes = paths[:1], (64,), (1, 2), (1,), (False,)
        frames, warmup = 3, 1
    rows, started = [], time.monotonic()
    for path in paths:
        identity = Identity.load(path)
        remade: dict[int, Identity] = {}
        bodies_at = _bodies(rig, rotations, roots)
        jobs = [(f"Module A @ {r}²", replace(RuntimeConfig(**RAW), uv_resolution=r), batch, False)
                for r in resolutions for batch in batches]
        jobs += [(runtime_label(shipped), shipped, batch, True) for batch in runtime_batches]
        for what, config, batch, contact in jobs:
            for bfloat16 in dtypes:
                row = DeviceRow(GARMENT, identity.num_vertices, what, batch, "bf16" if bfloat16 else "fp32",
                                None, None)
                if time.monotonic() - started > seconds:
                    row.missing = "not timed (job time)"
                else:
                    try:
                        resolution = config.uv_resolution or identity.raster.resolution
                        if resolution not in remade:  # once per resolution, not per batch and dtype
                            remade[resolution] = identity.at_resolution(resolution)
                        simulator = Simulator(module_a, [remade[resolution]] * batch, the_device,
                                              body_faces=rig.faces if contact else None,
                                              config=replace(config, bfloat16=bfloat16))
                        row.dtype = "bf16" if simulator.conv_mlp_dtype == torch.bfloat16 else "fp32"  # what ran
                        row.ms_per_frame = _median_ms(simulator, rotations, roots, bodies_at if contact else None,
                                                      the_device, warmup, frames, row_seconds)
                        row.ms_per_character = row.ms_per_frame / batch
                    except torch.cuda.OutOfMemoryError:
                        pass
                    finally:
                        simulator = None
                        if the_device.type == "cuda":
                            torch.cuda.empty_cache()
                rows.append(row)
                print(_row_line(row), flush=True)
                if on_row is not None:
                    on_row(rows)
    return rows


def _median_ms(simulator, rotations: torch.Tensor, roots: torch.Tensor, bodies_at, device: torch.device,
               warmup: int, frames: int, row_seconds: float) -> float:
    """Median ms of ``simulator``'s frames along the walk, its characters all in the same pose
    (rotations (T,31,3,3), roots (T,3); ``bodies_at``: t -> (1,Vb,3) the posed body, None
    without contact): up to ``frames`` frames after up to ``warmup``, fewer where the first
    frame says they would take more than ``row_seconds``."""
    from hyperbones.jobs.timing import timed_blocks

    batch = len(simulator.identities)

    def step(t: int) -> None:
        t = t % rotations.shape[0]
        simulator.step(rotations[t:t + 1].expand(batch, 31, 3, 3), roots[t:t + 1].expand(batch, 3),
                       bodies_at(t).expand(batch, -1, -1) if bodies_at is not None else None)

    first = timed_blocks(step, device, 1, 1)[0].median / 1000  # seconds, after one untimed frame
    count = max(3, min(frames, int(row_seconds / max(first, 1e-9))))
    return timed_blocks(step, device, max(1, min(warmup, count // 2)), count)[0].median


def _bodies(rig, rotations: torch.Tensor, roots: torch.Tensor):
    """t -> (1,Vb,3) the body posed at frame t (posed once per frame and kept)."""
    cache: dict[int, torch.Tensor] = {}

    def at(t: int) -> torch.Tensor:
        if t not in cache:
            cache[t] = rig.pose(rotations[t:t + 1], roots[t:t + 1])
        return cache[t]

    return at


HEADER = ("| garment | vertices | what | batch | dtype | ms/frame (median) | ms per character-frame |\n"
          "|---|---:|---|---:|---|---:|---:|")


def _row_line(row: DeviceRow) -> str:
    def ms(value):
        return row.missing if value is None else f"{value:.3f}"

    return (f"| {row.garment} | {row.vertices} | {row.what} | {row.batch} | {row.dtype} | {ms(row.ms_per_frame)} | "
            f"{ms(row.ms_per_character)} |")


def table(rows: list[DeviceRow], device: torch.device) -> str:
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "CPU"
    lines = [f"Device: {name}; torch {torch.__version__}; {time.strftime('%Y-%m-%d')}", "", HEADER]
    return "\n".join(lines + [_row_line(row) for row in rows])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hyperbones.jobs.device_bench", description=__doc__.split("\n")[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    prep = verbs.add_parser("prepare", help="write the inputs (needs Anny and Warp)")
    prep.add_argument("--out", required=True)
    prep.add_argument("--vertices", default=",".join(map(str, VERTICES)), help="garment sizes, comma-separated")
    go = verbs.add_parser("run", help="time the runtime on the prepared inputs (torch alone)")
    go.add_argument("--folder", required=True)
    go.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    go.add_argument("--quick", action="store_true", help="smallest garment, 64², batches 1-2, fp32, 3 frames")
    go.add_argument("--out", default=None, help="also write the table to this file")
    args = parser.parse_args(argv)
    if args.verb == "prepare":
        for path in prepare(args.out, tuple(int(v) for v in args.vertices.split(","))):
            print(path)
        return 0
    print(HEADER, flush=True)

    def write(rows: list[DeviceRow]) -> None:
        if args.out:
            with atomic_path(args.out) as staged:
                staged.write_text(table(rows, torch.device(args.device)) + "\n")

    rows = run(args.folder, args.device, args.quick, on_row=write)
    print("\n" + table(rows, torch.device(args.device)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
