"""Input validation and axis conversion shared by the exporters (private)."""

from __future__ import annotations

import math

import numpy as np

from hyperbones.errors import ParameterError


def frames_array(name: str, values, *, allow_static: bool = False) -> np.ndarray:
    """``values`` as a float array of shape (T,V,3) (or (V,3) when ``allow_static``), finite."""
    array = np.asarray(values)
    if array.dtype.kind not in "iuf":
        raise ParameterError(f"{name} must be a numeric array, got dtype {array.dtype}")
    if array.dtype != np.float64:
        array = array.astype(np.float32, copy=False)
    shapes = "(T,V,3) or (V,3)" if allow_static else "(T,V,3)"
    ok_ndim = array.ndim == 3 or (allow_static and array.ndim == 2)
    if not ok_ndim or array.shape[-1] != 3:
        raise ParameterError(f"{name} must have shape {shapes}, got {array.shape}")
    if array.ndim == 3 and array.shape[0] == 0:
        raise ParameterError(f"{name} has no frames (shape {array.shape})")
    if array.shape[-2] == 0:
        raise ParameterError(f"{name} has no vertices (shape {array.shape})")
    if not np.isfinite(array).all():
        raise ParameterError(f"{name} contains NaN or infinite values")
    return array


def faces_array(name: str, faces, n_vertices: int) -> np.ndarray:
    """``faces`` as an int64 (F,3) array whose indices lie in [0, n_vertices)."""
    array = np.asarray(faces)
    if array.ndim != 2 or array.shape[1] != 3:
        raise ParameterError(f"{name} must have shape (F,3) (triangles), got {array.shape}")
    if array.size and not np.issubdtype(array.dtype, np.integer):
        if not np.issubdtype(array.dtype, np.floating) or not np.array_equal(array, np.round(array)):
            raise ParameterError(f"{name} must hold integer vertex indices, got dtype {array.dtype}")
    array = array.astype(np.int64)
    if array.size and (array.min() < 0 or array.max() >= n_vertices):
        raise ParameterError(
            f"{name} indices must lie in [0, {n_vertices}), got [{array.min()}, {array.max()}]")
    return array


def uv_arrays(uvs, face_uvs, faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Validated ``(uvs (U,2) float, face_uvs (F,3) int64)`` or None when no UVs are given.

    ``face_uvs`` may be omitted when there is one UV per vertex (U == V): the faces index both.
    """
    if uvs is None:
        if face_uvs is not None:
            raise ParameterError("face_uvs was given without uvs")
        return None
    uv = np.asarray(uvs, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2 or uv.shape[0] == 0:
        raise ParameterError(f"uvs must have shape (U,2) with U > 0, got {uv.shape}")
    if not np.isfinite(uv).all():
        raise ParameterError("uvs contains NaN or infinite values")
    if face_uvs is None:
        if uv.shape[0] != n_vertices:
            raise ParameterError(
                f"uvs without face_uvs needs one UV per vertex ({n_vertices}), got {uv.shape[0]}")
        return uv, faces
    fuv = faces_array("face_uvs", face_uvs, uv.shape[0])
    if fuv.shape != faces.shape:
        raise ParameterError(f"face_uvs must have the shape of faces {faces.shape}, got {fuv.shape}")
    return uv, fuv


def check_up(up: str, name: str = "up") -> str:
    """``"Z"`` or ``"Y"`` (case-insensitive)."""
    value = str(up).upper()
    if value not in ("Z", "Y"):
        raise ParameterError(f"{name} must be 'Z' or 'Y', got {up!r}")
    return value


def to_up(points: np.ndarray, up: str) -> np.ndarray:
    """Convert Z-up points to ``up``: unchanged for "Z"; (x,y,z) -> (x,z,-y) for "Y"."""
    if up == "Z":
        return points
    out = np.empty_like(points)
    out[..., 0] = points[..., 0]
    out[..., 1] = points[..., 2]
    out[..., 2] = -points[..., 1]
    out[..., 2] += 0.0  # -0.0 -> 0.0, so files do not show "-0.000000"
    return out


def check_positive(name: str, value) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number) or number <= 0:
        raise ParameterError(f"{name} must be a positive number, got {value!r}")
    return number
