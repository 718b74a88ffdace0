"""From what the user names (a template, an OBJ, a MakeHuman .mhclo) to a draped garment.

Draping takes seconds to minutes, so draped garments are cached on disk, keyed by
everything that determines them (``HYPERBONES_CACHE_DIR``, default ~/.cache/hyperbones).
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from dataclasses import asdict
from pathlib import Path

import torch

from hyperbones.body.anny_body import Body, body_for
from hyperbones.body.shape import BodyShape
from hyperbones.errors import InputFileError, ParameterError
from hyperbones.garment.drape import drape, transfer
from hyperbones.garment.garment import Garment
from hyperbones.garment.mhclo import load_mhclo_garment
from hyperbones.garment.obj_io import load_obj_garment
from hyperbones.garment.templates import DEFAULT_VERTICES, TEMPLATES, make_template
from hyperbones.io_utils import atomic_path
from hyperbones.physics.material import Material

CACHE_VERSION = 6


def cache_dir() -> Path:
    return Path(os.environ.get("HYPERBONES_CACHE_DIR", Path.home() / ".cache" / "hyperbones"))


def _undraped(source: str, body: Body, vertices: int | None, piece: int | None) -> tuple[Garment, torch.Tensor | None]:
    """The garment before draping on ``body`` and its rest (pattern) shape, or None when
    the fit itself is the rest shape (templates, MakeHuman clothes)."""
    if source in TEMPLATES:
        return make_template(source, body, vertices or DEFAULT_VERTICES), None
    path = Path(source)
    if path.suffix.lower() == ".mhclo":
        return load_mhclo_garment(path, body, piece=piece), None
    if path.suffix.lower() == ".obj":
        # An OBJ garment is made for the default body: its pattern stays, the body changes.
        garment = load_obj_garment(path)
        default = body_for(BodyShape())
        moved = garment if body.shape == default.shape else transfer(garment, default, body)
        return moved, garment.vertices
    if path.suffix:
        raise InputFileError(path, "not a garment file (expected .obj or .mhclo)")
    raise ParameterError(f"unknown garment {source!r}: give a template ({', '.join(TEMPLATES)}), an .obj or an .mhclo")


def _key(source: str, body: Body, vertices: int | None, piece: int | None, material: Material) -> str:
    identity = {"source": source, "body": body.shape.as_dict(), "vertices": vertices, "piece": piece,
                "material": material.as_dict(), "version": CACHE_VERSION}
    path = Path(source)
    if path.exists():
        identity["source"] = str(path.resolve())
        identity["mtime"] = path.stat().st_mtime_ns
    return hashlib.sha1(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:16]


def draped_garment(source: str, body: Body, *, vertices: int | None = None, piece: int | None = None,
                   material: Material | None = None, use_cache: bool = True) -> tuple[Garment, torch.Tensor]:
    """The garment draped on ``body``'s canonical pose, and its rest shape (V,3).

    Args:
        source: a template name, or a path to an .obj (fitted to the default body) or .mhclo.
        vertices: template resolution (default ``DEFAULT_VERTICES``).
        piece: which piece of a multi-piece MakeHuman outfit.
        material: the cloth (HOOD's defaults when None).
    """
    material = material or Material()
    if source not in TEMPLATES and not Path(source).exists():
        if Path(source).suffix:
            raise InputFileError(source, "file not found")
    key = _key(source, body, vertices, piece, material)
    path = cache_dir() / "garments" / f"{key}.pt"
    if use_cache and path.exists():
        data = torch.load(path, weights_only=True)
        garment = Garment(data["vertices"], data["faces"], data["uvs"], data["face_uvs"], data["pinned"],
                          Material(**data["material"]), data["name"])
        return garment, data["rest_vertices"]
    undraped, rest_vertices = _undraped(source, body, vertices, piece)
    undraped = Garment(undraped.vertices, undraped.faces, undraped.uvs, undraped.face_uvs, undraped.pinned,
                       material, undraped.name)
    from hyperbones.physics.cloth import ClothRest

    rest = None if rest_vertices is None else ClothRest.from_mesh(rest_vertices.double(), undraped.faces, material)
    garment, report = drape(undraped, body, rest=rest)
    if not report.converged:
        warnings.warn(f"the drape of {undraped.name} stopped after {report.iterations} Newton iterations short of force "
                      f"balance (95th percentile of unbalanced force / weight {report.force_ratio_p95:.3f}); "
                      "it starts from there", stacklevel=2)
    if rest_vertices is None:
        rest_vertices = report.rest_vertices
    if use_cache:
        with atomic_path(path) as tmp:
            torch.save({"vertices": garment.vertices, "faces": garment.faces, "uvs": garment.uvs,
                        "face_uvs": garment.face_uvs, "pinned": garment.pinned, "rest_vertices": rest_vertices,
                        "material": asdict(material), "name": garment.name}, tmp)
    return garment, rest_vertices
