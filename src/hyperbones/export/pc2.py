"""PC2 point caches (the "Point Cache 2" format read by Blender's Mesh Cache modifier).

Layout (all little-endian, no padding; 32-byte header, as in Blender's
``source/blender/modifiers/intern/MOD_meshcache_pc2.cc`` struct ``PC2Head``)::

    offset  type       field
         0  char[12]   signature  b"POINTCACHE2\\0"
        12  int32      file version, 1
        16  int32      number of points V
        20  float32    start frame
        24  float32    sample rate: frames between two samples (1.0 = one sample per frame)
        28  int32      number of samples T
        32  float32    T x V x 3 coordinates, sample-major: sample 0 points 0..V-1 (x,y,z), ...

The format stores no frames-per-second value: a consumer plays sample ``i`` at frame
``start + i * sample_rate`` of its own timeline (Blender's modifier in "Frames" time mode
simply uses sample index = scene frame), so the scene should run at the ``fps`` the frames
were computed at.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.export._checks import check_positive, check_up, frames_array, to_up
from hyperbones.io_utils import atomic_path

PC2_SIGNATURE = b"POINTCACHE2\0"
PC2_VERSION = 1
PC2_HEADER = struct.Struct("<12siiffi")  # 32 bytes
_MAX_INT32 = 2**31 - 1


def write_pc2(
    path: str | Path,
    vertices,
    fps: float = 30.0,
    start_frame: float = 0.0,
    *,
    sample_rate: float = 1.0,
    up: str = "Z",
) -> Path:
    """Write (T,V,3) vertex positions to a PC2 point cache at ``path`` (atomically).

    Args:
        vertices: (T,V,3) positions in metres, Z up; stored as float32.
        fps: the frame rate the samples were computed at. PC2 has no field for it: it is
            validated only, and the scene that plays the cache should use it.
        start_frame: written to the header's start-frame field.
        sample_rate: written to the header's sample-rate field, the number of frames
            between consecutive samples; 1.0 (the default) = one sample per frame.
        up: ``"Z"`` writes the coordinates as given; ``"Y"`` converts to Y up,
            (x,y,z) -> (x,z,-y).

    Returns the path written.
    """
    check_positive("fps", fps)
    sample_rate = check_positive("sample_rate", sample_rate)
    try:
        start = float(start_frame)
    except (TypeError, ValueError):
        raise ParameterError(f"start_frame must be a number, got {start_frame!r}") from None
    if not np.isfinite(start):
        raise ParameterError(f"start_frame must be finite, got {start_frame!r}")
    up = check_up(up)
    verts = frames_array("vertices", vertices)
    n_samples, n_points = verts.shape[:2]
    if n_points > _MAX_INT32 or n_samples > _MAX_INT32:
        raise ParameterError(f"vertices shape {verts.shape} exceeds the PC2 int32 counts")
    data = np.ascontiguousarray(to_up(verts, up), dtype="<f4")
    header = PC2_HEADER.pack(PC2_SIGNATURE, PC2_VERSION, n_points, start, sample_rate, n_samples)
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(header)
            f.write(memoryview(data).cast("B"))
    return path


def read_pc2(path: str | Path) -> tuple[np.ndarray, float, float]:
    """Read a PC2 point cache: ``(vertices (T,V,3) float32, start_frame, sample_rate)``.

    Coordinates are returned as stored. Raises InputFileError for a missing or unreadable
    file, a wrong signature, negative counts, a file whose size does not match its header,
    a non-finite start frame or non-positive sample rate, or NaN / infinite coordinates.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            raw = f.read(PC2_HEADER.size)
            if len(raw) < PC2_HEADER.size:
                if raw[:12] and not PC2_SIGNATURE.startswith(raw[:12]):
                    raise InputFileError(path, "not a PC2 point cache (wrong signature)")
                raise InputFileError(
                    path, f"truncated PC2 file: {size} bytes, the header alone needs {PC2_HEADER.size}")
            signature, _version, n_points, start, sample_rate, n_samples = PC2_HEADER.unpack(raw)
            if signature != PC2_SIGNATURE:
                raise InputFileError(
                    path, f"not a PC2 point cache (signature {signature!r}, expected {PC2_SIGNATURE!r})")
            if n_points < 0 or n_samples < 0:
                raise InputFileError(
                    path, f"corrupt PC2 header: {n_points} points, {n_samples} samples")
            expected = PC2_HEADER.size + 12 * n_points * n_samples
            if size < expected:
                raise InputFileError(
                    path, f"truncated PC2 file: {size} bytes, but {n_samples} samples of "
                          f"{n_points} points need {expected}")
            if size > expected:
                raise InputFileError(
                    path, f"PC2 file has {size - expected} bytes after the {n_samples} samples of "
                          f"{n_points} points its header announces")
            data = np.fromfile(f, dtype="<f4", count=n_samples * n_points * 3)
    except OSError as exc:
        raise InputFileError(path, f"cannot read: {exc.strerror or exc}") from None
    if not np.isfinite(start) or not 0 < sample_rate < np.inf:
        raise InputFileError(path, f"corrupt PC2 header: start frame {start}, sample rate {sample_rate}")
    if not np.isfinite(data).all():
        first = int(np.argmin(np.isfinite(data))) // 3
        raise InputFileError(path, f"NaN or infinite coordinates (first at sample {first // max(n_points, 1)}, "
                                   f"point {first % max(n_points, 1)})")
    vertices = data.astype(np.float32, copy=False).reshape(n_samples, n_points, 3)
    return vertices, float(start), float(sample_rate)
