"""One animated mesh of an exported scene, and its validation, shared by the USD and glTF writers."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hyperbones.errors import ParameterError
from hyperbones.export._checks import faces_array, frames_array, to_up, uv_arrays


@dataclass
class SceneMesh:
    """One mesh for :func:`~hyperbones.export.write_usd` or :func:`~hyperbones.export.write_gltf`.

    Attributes:
        name: the mesh's name in the scene (for USD a prim name under ``/Root``: letters,
            digits, ``_``; not starting with a digit).
        vertices: (T,V,3) animated or (V,3) static positions, metres, Z up.
        faces: (F,3) 0-based triangle vertex indices.
        uvs: optional (U,2) texture coordinates (origin bottom left, as in OBJ and USD).
        face_uvs: optional (F,3) indices into ``uvs`` per face corner (seams). When omitted
            with ``uvs`` of shape (V,2), the faces index both.
        display_color: optional RGB in [0, 1], (3,) for the whole mesh or (V,3) per vertex.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None
    face_uvs: np.ndarray | None = None
    display_color: tuple[float, float, float] | np.ndarray | None = None


@dataclass
class CheckedMesh:
    """A validated ``SceneMesh`` in the writer's axes and units.

    points: (T,V,3) or (V,3) float32; faces: (F,3) int64; uv: ((U,2) float64, (F,3) int64
    corner indices) or None; color: (1,3) or (V,3) float32, or None.
    """

    name: str
    points: np.ndarray
    faces: np.ndarray
    uv: tuple[np.ndarray, np.ndarray] | None
    color: np.ndarray | None


def checked_meshes(meshes, up: str, meters_per_unit: float, writer: str) -> list[CheckedMesh]:
    """``meshes`` (one ``SceneMesh`` or a list) validated (``ParameterError`` naming the mesh
    and the problem) and converted to ``up`` ("Z" or "Y") and the unit; ``writer`` names the
    calling function in messages. Animated meshes must share one frame count."""
    if isinstance(meshes, SceneMesh):
        meshes = [meshes]
    meshes = list(meshes)
    if not meshes:
        raise ParameterError(f"{writer} needs at least one mesh")
    names: set[str] = set()
    frame_counts: set[int] = set()
    checked = []
    for mesh in meshes:
        if not isinstance(mesh, SceneMesh):
            raise ParameterError(f"meshes must be SceneMesh instances, got {type(mesh).__name__}")
        if not isinstance(mesh.name, str) or not mesh.name:
            raise ParameterError(f"mesh name {mesh.name!r} must be a non-empty string")
        if mesh.name in names:
            raise ParameterError(f"two meshes are named {mesh.name!r}")
        names.add(mesh.name)
        label = f"mesh {mesh.name!r}"
        points = frames_array(f"{label} vertices", mesh.vertices, allow_static=True)
        n_vertices = points.shape[-2]
        if points.ndim == 3:
            frame_counts.add(points.shape[0])
        faces = faces_array(f"{label} faces", mesh.faces, n_vertices)
        uv = uv_arrays(mesh.uvs, mesh.face_uvs, faces, n_vertices)
        color = None
        if mesh.display_color is not None:
            color = np.asarray(mesh.display_color, dtype=np.float32)
            if color.shape == (3,):
                color = color[None]
            elif color.shape != (n_vertices, 3):
                raise ParameterError(
                    f"{label} display_color must have shape (3,) or ({n_vertices},3), got {color.shape}")
            if not np.isfinite(color).all():
                raise ParameterError(f"{label} display_color contains NaN or infinite values")
        points = to_up(points, up)
        if meters_per_unit != 1.0:
            points = points / meters_per_unit
        checked.append(CheckedMesh(mesh.name, np.ascontiguousarray(points, dtype=np.float32), faces, uv, color))
    if len(frame_counts) > 1:
        raise ParameterError(f"animated meshes have different frame counts: {sorted(frame_counts)}")
    return checked
