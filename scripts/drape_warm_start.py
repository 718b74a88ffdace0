"""Training drapes started cold (from the garment carried to the body) and warm (from the
template's drape on the default body, carried to the body the same way), side by side.

A draped bank rollout spends most of its time in the drape (``scripts/bank_draws.py``): the
Newton solve starts from the carried garment, which then slides and settles over hundreds of
iterations. The default body's drape already did that sliding once per template; carried to
the new body it is a start near rest. Prints one Markdown row per (template, body): seconds,
Newton iterations, whether it converged, the force balance p95, the edge error, and how far
apart the two results end (mean and max, mm).

Usage: ``OMP_NUM_THREADS=1 python scripts/drape_warm_start.py [--templates ...] [--bodies 2]
[--vertices 1500] [--seed 0]``.
"""

from __future__ import annotations

import argparse
import random
import time
import warnings

import torch

from hyperbones.body.anny_body import body_for
from hyperbones.body.shape import BodyShape, draw_training_shape
from hyperbones.garment.drape import drape
from hyperbones.physics.cloth import ClothRest
from hyperbones.training.config import DataConfig
from hyperbones.training.data import template_source
from hyperbones.training.shape_follower import ShapeFollower


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--templates", default="tshirt,tshirt-open,pants,long-skirt,dress,tight-dress")
    parser.add_argument("--bodies", type=int, default=2, help="training shapes drawn per template")
    parser.add_argument("--vertices", type=int, default=1500)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    config = DataConfig()
    held_out = [BodyShape.parse(text) for text in config.test_bodies]
    draws = random.Random(args.seed)
    default_body = body_for(BodyShape())
    print("| template | body | start | s | iterations | converged | force p95 | ε_e % | apart mean / max mm |")
    print("|---|---|---|---:|---:|---|---:|---:|---:|")
    for name in args.templates.split(","):
        source = template_source(name, args.vertices, default_body)
        with warnings.catch_warnings(), torch.enable_grad():
            warnings.simplefilter("ignore")
            settled, _ = drape(source.garment, default_body)
        draped_follower = ShapeFollower.bind(settled, default_body)
        for index in range(args.bodies):
            body = body_for(draw_training_shape(draws.random, held_out, config.test_body_margin))
            carried = source.follower.place(body)
            garment = source.garment.with_vertices(carried)
            results = {}
            for start, begin in (("cold", garment), ("warm", garment.with_vertices(draped_follower.place(body)))):
                rest = ClothRest.from_mesh(carried.double(), garment.faces, garment.material)
                started = time.perf_counter()
                with warnings.catch_warnings(), torch.enable_grad():
                    warnings.simplefilter("ignore")
                    result, report = drape(begin, body, rest=rest)
                seconds = time.perf_counter() - started
                results[start] = result.vertices
                apart = ""
                if start == "warm":
                    distance = (results["warm"] - results["cold"]).norm(dim=-1) * 1000
                    apart = f"{float(distance.mean()):.1f} / {float(distance.max()):.1f}"
                print(f"| {name} | {index} | {start} | {seconds:.1f} | {report.iterations} | {report.converged} "
                      f"| {report.force_ratio_p95:.3f} | {report.edge_error_pct:.2f} | {apart} |", flush=True)


if __name__ == "__main__":
    main()
