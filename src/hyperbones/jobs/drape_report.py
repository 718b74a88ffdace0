"""Drape quality over garments x resolutions x body shapes, for ``hyperbones check drape``."""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

from tqdm import tqdm

from hyperbones.body import BodyShape, body_for
from hyperbones.garment.drape import drape
from hyperbones.garment.mhclo import list_pieces, load_mhclo_garment
from hyperbones.garment.templates import TEMPLATES, make_template
from hyperbones.geometry.proximity import BodyProximity

CORNER_BODIES = ("gender=0,weight=0,height=0", "gender=1,muscle=1,weight=1,height=1",
                 "gender=1,weight=0,height=0,proportions=1")


HEADER = ("| garment | vertices | body | penetrating before | collision % after | edge error % | "
          "area error % | force p95 | force max | last step mm | at rest | iterations | make s | drape s |\n"
          "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|")


def drape_rows(resolutions: list[int], bodies: list[str], mhclo_files: list[Path],
               templates: Iterable[str] = tuple(TEMPLATES), progress: bool = True) -> Iterator[str]:
    """One markdown row (see ``HEADER``) per garment and body, yielded as each drape ends:
    collision % (d < 0) and edge/area error % after draping, and how close to rest the drape
    got: the 95th percentile and maximum over free vertices of |∇E_i| / (m_i g), the longest
    vertex move of its last Newton step, whether either met its tolerance, and its Newton
    iterations."""
    templates = tuple(templates)
    jobs = [(name, n) for name in templates for n in resolutions]
    jobs += [(str(path), None) for path in mhclo_files]
    bar = tqdm(total=len(bodies) * (len(templates) * len(resolutions) + 2 * len(mhclo_files)),
               desc="drape", disable=not progress)
    for body_text in bodies:
        body = body_for(BodyShape.parse(body_text))
        proximity = BodyProximity(body.faces)
        proximity.update(body.rest_vertices)
        for source, resolution in jobs:
            pieces = [None] if resolution else range(len(list_pieces(source, body)))
            for piece in pieces:
                start = time.perf_counter()
                if resolution:
                    garment = make_template(source, body, resolution)
                    label = source
                else:
                    garment = load_mhclo_garment(source, body, piece=piece)
                    label = f"{Path(source).stem} piece {piece}"
                made = time.perf_counter()
                draped, report = drape(garment, body)
                took = time.perf_counter() - made
                distance = proximity.query(draped.vertices, max_distance=0.5).signed_distance
                collision = 100.0 * float((distance < 0).float().mean())
                bar.update(1)
                yield (f"| {label} | {garment.num_vertices} | {body.shape.label()} | {report.penetrating_before} | "
                       f"{collision:.3f} | {report.edge_error_pct:.2f} | {report.area_error_pct:.2f} | "
                       f"{report.force_ratio_p95:.3f} | {report.force_ratio_max:.1f} | {_millimetres(report.newton_step_max)} | "
                       f"{'yes' if report.converged else 'no'} | {report.iterations} | "
                       f"{made - start:.1f} | {took:.1f} |")
    bar.close()


__all__ = ["CORNER_BODIES", "HEADER", "drape_rows"]


def _millimetres(metres: float) -> str:
    return "–" if math.isnan(metres) else f"{1000 * metres:.3f}"
