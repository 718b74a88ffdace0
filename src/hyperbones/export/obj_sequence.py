"""Write an animated triangle mesh as a sequence of Wavefront OBJ files, one per frame."""

from __future__ import annotations

import os
import re
import shutil
import uuid
from pathlib import Path

import numpy as np

from hyperbones.errors import ParameterError

from hyperbones.io_utils import output_error
from hyperbones.export._checks import check_up, faces_array, frames_array, to_up, uv_arrays

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


def write_obj_sequence(
    directory: str | Path,
    vertices,
    faces,
    *,
    uvs=None,
    face_uvs=None,
    name: str = "garment",
    up: str = "Z",
) -> list[Path]:
    """Write ``directory/name_0000.obj`` ... one OBJ per frame and return their paths.

    Args:
        directory: output folder (created, parents included).
        vertices: (T,V,3) positions in metres, Z up.
        faces: (F,3) 0-based vertex indices (written 1-based, as OBJ wants).
        uvs: optional (U,2) texture coordinates, written as ``vt`` lines.
        face_uvs: optional (F,3) 0-based indices into ``uvs`` per face corner, so seams can
            split UVs without splitting vertices; faces are then written ``f v/vt v/vt v/vt``.
            When omitted with ``uvs`` of shape (V,2), the faces index both.
        name: file-name stem and OBJ object name (letters, digits, ``._-``).
        up: ``"Z"`` writes the coordinates as given; ``"Y"`` converts to Y up,
            (x,y,z) -> (x,z,-y), for tools that assume it.

    Coordinates are written with 6 decimals (micrometres). Frame numbers have 4 digits
    (more when T > 10000), starting at 0. The sequence is written atomically: all frames go
    into a staging folder and are moved into place only once every frame is written; files
    ``name_NNNN.obj`` left in ``directory`` from an earlier, longer sequence are removed so
    that importers do not pick up stale frames. Other files in ``directory`` are untouched.
    A folder that cannot be written (read-only, full disk) is an ``OutputError``.
    """
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise ParameterError(f"name must be letters, digits, '.', '_' or '-', got {name!r}")
    up = check_up(up)
    verts = frames_array("vertices", vertices)
    n_frames, n_vertices = verts.shape[:2]
    tris = faces_array("faces", faces, n_vertices)
    uv = uv_arrays(uvs, face_uvs, tris, n_vertices)
    verts = to_up(verts, up)

    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise ParameterError(f"{directory}: exists and is not a directory")

    width = max(4, len(str(n_frames - 1)))
    file_names = [f"{name}_{i:0{width}d}.obj" for i in range(n_frames)]
    tail = _static_tail(tris, uv)
    vertex_line = "v %.6f %.6f %.6f\n" * n_vertices

    created = not directory.exists()
    staging_parent = directory.parent if created else directory
    staging = staging_parent / f".{directory.name}.{uuid.uuid4().hex[:8]}.tmp"
    try:
        directory.parent.mkdir(parents=True, exist_ok=True)
        os.mkdir(staging)
        for index, file_name in enumerate(file_names):
            header = (f"# hyperbones {name} frame {index} of {n_frames}, metres, {up} up\n"
                      f"o {name}\n")
            text = header + _vertex_block(vertex_line, verts[index]) + tail
            (staging / file_name).write_bytes(text.encode("ascii"))
        _commit(staging, directory, created, file_names, name)
    except BaseException as error:
        shutil.rmtree(staging, ignore_errors=True)
        failure = output_error(directory, error) if isinstance(error, OSError) else None
        if failure is None:
            raise
        raise failure from error
    return [directory / file_name for file_name in file_names]


def _vertex_block(vertex_line: str, points: np.ndarray) -> str:
    """All ``v`` lines of one frame with a single C-level %-format (no per-vertex Python loop)."""
    return vertex_line % tuple(points.ravel().tolist())


def _static_tail(faces: np.ndarray, uv: tuple[np.ndarray, np.ndarray] | None) -> str:
    """The ``vt`` and ``f`` lines, identical in every frame, formatted once."""
    one_based = (faces + 1).ravel().tolist()
    if uv is None:
        return "s off\n" + ("f %d %d %d\n" * len(faces)) % tuple(one_based)
    coords, face_uvs = uv
    vt = ("vt %.6f %.6f\n" * len(coords)) % tuple(coords.ravel().tolist())
    corners = np.stack([faces + 1, face_uvs + 1], axis=-1).ravel().tolist()
    f = ("f %d/%d %d/%d %d/%d\n" * len(faces)) % tuple(corners)
    return vt + "s off\n" + f


def _commit(staging: Path, directory: Path, created: bool, file_names: list[str], name: str) -> None:
    """Move the finished frames from ``staging`` into ``directory``."""
    if created:
        try:
            os.replace(staging, directory)  # the whole folder appears at once
            return
        except OSError:
            if not directory.is_dir():  # created meanwhile by someone else: merge below
                raise
    for file_name in file_names:
        os.replace(staging / file_name, directory / file_name)
    keep = set(file_names)
    pattern = re.compile(re.escape(name) + r"_\d{4,}\.obj")
    for stale in directory.iterdir():
        if stale.name not in keep and pattern.fullmatch(stale.name) and stale.is_file():
            stale.unlink()
    staging.rmdir()
