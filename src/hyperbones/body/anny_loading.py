"""A faster reader for Anny's blend-shape files, used when Anny builds its cache.

Anny's first construction on a machine parses ~1,100 gzipped text targets (lines
"vertex_id dx dy dz") one line at a time, making a tensor per line: most of `hyperbones
demo`'s first run. ``read_blend_shape`` parses a whole file at once with numpy and gives the
same tensor, bit for bit (``tests/test_body_anny.py`` checks it against Anny's own reader;
timings: docs/experiments/*-anny-cache-reader.md). ``install`` swaps it in for anny 0.6.2, the version pinned in
pyproject.toml, whose reader it mirrors; for any other version Anny's own reader stays.
"""

from __future__ import annotations

import gzip
import importlib.metadata

import numpy as np
import torch

MIRRORED_VERSION = "0.6.2"
annys_reader = None
"""Anny's own reader, kept by ``install`` when it swaps it out (None before)."""


def read_blend_shape(filename, vertices_count: int, world_transformation, dtype: torch.dtype) -> torch.Tensor:
    """One target file -> (vertices_count,3) offsets in Anny's world frame (zero where absent).

    Same contract as ``anny.models.full_model.load_blend_shape``: ids index the template's
    vertices, offsets are in decimetres until ``world_transformation.apply``.
    """
    with gzip.open(filename, "rb") as archive:
        table = np.array(archive.read().split(), dtype=np.float64)
    if table.size % 4:
        raise ValueError(f"{filename}: expected lines of 'vertex_id dx dy dz'")
    table = table.reshape(-1, 4)
    ids = table[:, 0].astype(np.int64)
    if ids.size and (ids.min() < 0 or ids.max() >= vertices_count or not np.array_equal(ids, table[:, 0])):
        raise ValueError(f"{filename}: vertex ids outside 0..{vertices_count - 1}")
    blend_shape = torch.zeros((vertices_count, 3), dtype=dtype)
    # Anny writes the lines in order, the last line of a repeated id winning; keep that.
    _, last = np.unique(ids[::-1], return_index=True)
    keep = ids.size - 1 - last
    blend_shape[torch.from_numpy(ids[keep])] = torch.from_numpy(table[keep, 1:]).to(dtype)
    return world_transformation.apply(blend_shape)


def install() -> bool:
    """Use ``read_blend_shape`` for Anny's cache build; True when installed (anny 0.6.2)."""
    try:
        version = importlib.metadata.version("anny")
        from anny.models import full_model
    except (importlib.metadata.PackageNotFoundError, ImportError):
        return False
    global annys_reader
    if version != MIRRORED_VERSION or not hasattr(full_model, "load_blend_shape"):
        return False
    if full_model.load_blend_shape is not read_blend_shape:
        annys_reader = full_model.load_blend_shape
        full_model.load_blend_shape = read_blend_shape
    return True
