"""Where a simulated garment's inertia sits: on the skin, near it, or loose.

Reads the ``frames.npz`` of ``hyperbones simulate`` outputs and prints one Markdown row per
run: the per-vertex inertia m‖x_t − 2x_{t−1} + x_{t−2}‖² / (2Δt²) (masses by vertex area at the
first frame, the garment weighing 1 kg: only ratios between runs compare), a mean over frames,
split by each vertex-frame's distance to the nearest body vertex (on the skin below
``--skin``, near below ``--near``, loose beyond), and the share of the on-skin part carried
by its top 1 % of vertex-frames (a few jolts, or a steady shake).
Usage: ``python scripts/inertia_by_skin_distance.py RUN_DIR [RUN_DIR ...] [--skin 0.015] [--near 0.04]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from hyperbones.errors import HyperbonesError, InputFileError
from hyperbones.physics.cloth import ClothRest


def vertex_masses(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V,3), (F,3) -> (V,) the cloth's lumped masses (``ClothRest``: a third of each adjacent
    triangle's), scaled to sum to 1 kg."""
    masses = ClothRest.from_mesh(torch.from_numpy(vertices), torch.from_numpy(faces).long()).vertex_masses.numpy()
    return masses / masses.sum()


def inertia_split(run: Path, skin: float, near: float) -> dict[str, float]:
    """One simulate output folder -> its inertia (J, 1 kg garment): all, on skin, near, loose,
    and the top 1 % of on-skin vertex-frames' share of the on-skin part."""
    path = run / "frames.npz"
    try:
        frames = np.load(path)
        garment = frames["garment_vertices"].astype(np.float64)  # (T,V,3)
        faces, body, fps = frames["garment_faces"], frames["body_vertices"], float(frames["fps"])
    except (OSError, KeyError, ValueError) as error:
        raise InputFileError(path, f"not a simulate output's frames ({type(error).__name__}: {error})") from None
    if len(garment) < 3:
        raise InputFileError(path, f"{len(garment)} frames: inertia needs at least 3")
    acceleration = garment[2:] - 2.0 * garment[1:-1] + garment[:-2]  # (T-2,V,3)
    energy = vertex_masses(garment[0], faces) * np.square(acceleration).sum(-1) * fps * fps / 2.0  # (T-2,V)
    distance = np.stack([cKDTree(body[t]).query(garment[t])[0] for t in range(2, len(garment))])
    bands = {"on skin": distance < skin, "near": (distance >= skin) & (distance < near), "loose": distance >= near}
    split = {"all": float(energy.sum(1).mean())}
    split.update({name: float((energy * band).sum(1).mean()) for name, band in bands.items()})
    on_skin = np.sort(energy[bands["on skin"]])[::-1]
    top = max(1, len(on_skin) // 100)
    split["top 1 % share"] = float(on_skin[:top].sum() / on_skin.sum()) if on_skin.sum() > 0 else 0.0
    return split


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="hyperbones simulate output folders")
    parser.add_argument("--skin", type=float, default=0.015, help="on the skin below this distance (m)")
    parser.add_argument("--near", type=float, default=0.04, help="near the skin below this distance (m)")
    args = parser.parse_args()
    try:
        rows = [(run, inertia_split(run, args.skin, args.near)) for run in args.runs]
    except HyperbonesError as error:
        raise SystemExit(f"error: {error}") from None
    print("| run | inertia J | on skin | near | loose | share on skin | top 1 % of on-skin vertex-frames |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for run, split in rows:
        print(f"| {run.name} | {split['all']:.5f} | {split['on skin']:.5f} | {split['near']:.5f} | "
              f"{split['loose']:.5f} | {split['on skin'] / split['all']:.2f} | {split['top 1 % share']:.2f} |")


if __name__ == "__main__":
    main()
