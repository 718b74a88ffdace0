"""Drape quality over garments x resolutions x body shapes, for ``hyperbones check drape``.

Each garment is draped on the default body first: its strain there is the reference that
the other bodies' strain is held against (a garment fitted to a body should rest on it about
as relaxed as on the default one; a much larger strain means its fit, drape and rest shape
disagree on that body, and every method downstream pulls against it). A garment fitted to a
larger body is larger, and under its own weight its strain energy grows about as the square of
its area (strain with its length, energy with strain squared times area): a strain over twice
the default body's is flagged only when it is also over twice that once divided by the area
ratio squared.
"""

from __future__ import annotations

import itertools
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
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.energies import stretching_energy

CORNER_BODIES = tuple(f"gender={gender},weight={weight},height={height}"
                      for gender, weight, height in itertools.product((0.1, 0.9), repeat=3))
"""The eight corners of (gender, weight, height) in {0.1, 0.9}, the rest of the shape at 0.5."""
STRAIN_FACTOR = 2.0  # flagged: a strain over this many times the default body's, with and without the size scaling

HEADER = ("| garment | vertices | body | penetrating before | collision % after | edge error % | area error % | "
          "strain J | area ÷ default's | strain ÷ default's | ÷ area ratio² | force p95 | at rest | iterations | "
          "drape s |\n|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|")


def _garments(templates: tuple[str, ...], resolutions: list[int], mhclo_files: list[Path], body) -> list[tuple]:
    """(label, maker(body) -> Garment) for every template × resolution and MakeHuman piece."""
    makers = [(name, lambda b, name=name, n=n: make_template(name, b, n)) for name in templates for n in resolutions]
    for path in mhclo_files:
        for piece in range(len(list_pieces(str(path), body))):
            makers.append((f"{path.stem} piece {piece}",
                           lambda b, path=path, piece=piece: load_mhclo_garment(str(path), b, piece=piece)))
    return makers


def drape_rows(resolutions: list[int], bodies: list[str], mhclo_files: list[Path],
               templates: Iterable[str] = tuple(TEMPLATES), progress: bool = True) -> Iterator[str]:
    """One markdown row (see ``HEADER``) per garment and body, yielded as each drape ends, the
    default body's first: collision % (d < 0), edge/area error % and the strain energy (J)
    of the drape against its rest shape, that strain over the default body's, and how close
    to rest the drape got (95th percentile over free vertices of |∇E_i| / (m_i g), whether
    it met its tolerance, Newton iterations). A strain ratio over ``STRAIN_FACTOR``, both as it
    is and divided by the rest area's ratio squared, is marked ✗."""
    shapes = [BodyShape()] + [shape for shape in map(BodyShape.parse, bodies) if shape != BodyShape()]
    makers = _garments(tuple(templates), resolutions, mhclo_files, body_for(shapes[0]))
    reference: dict[str, tuple[float, float]] = {}
    bar = tqdm(total=len(shapes) * len(makers), desc="drape", disable=not progress)
    for shape in shapes:
        body = body_for(shape)
        proximity = BodyProximity(body.faces)
        proximity.update(body.rest_vertices)
        for label, make in makers:
            garment = make(body)
            start = time.perf_counter()
            draped, report = drape(garment, body)
            took = time.perf_counter() - start
            rest_vertices = report.rest_vertices if report.rest_vertices is not None else garment.vertices
            rest = ClothRest.from_mesh(rest_vertices.double(), garment.faces, garment.material)
            strain = float(stretching_energy(draped.vertices.double(), rest))
            area = float(rest.face_areas.sum())
            strain_0, area_0 = reference.setdefault(label, (strain, area))
            ratio = strain / strain_0 if strain_0 > 0 else math.inf
            scaled = ratio / (area / area_0) ** 2
            flag = " ✗" if min(ratio, scaled) > STRAIN_FACTOR else ""
            distance = proximity.query(draped.vertices, max_distance=0.5).signed_distance
            collision = 100.0 * float((distance < 0).float().mean())
            bar.update(1)
            yield (f"| {label} | {garment.num_vertices} | {shape.label()} | {report.penetrating_before} | "
                   f"{collision:.3f} | {report.edge_error_pct:.2f} | {report.area_error_pct:.2f} | {strain:.4g} | "
                   f"{area / area_0:.3f} | {ratio:.2f} | {scaled:.2f}{flag} | {report.force_ratio_p95:.3f} | {'yes' if report.converged else 'no'} | "
                   f"{report.iterations} | {took:.1f} |")
    bar.close()


__all__ = ["CORNER_BODIES", "HEADER", "STRAIN_FACTOR", "drape_rows"]
