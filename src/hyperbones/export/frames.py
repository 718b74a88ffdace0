"""The ``frames.npz`` contract: a simulated sequence (garment, body, skeleton) in one archive.

Keys (always present):
    garment_vertices: (T,V,3) float32, metres, Z up.
    garment_faces: (F,3) int32, 0-based.
    body_vertices: (T,Vb,3) float32.
    body_faces: (Fb,3) int32.
    joint_positions: (T,31,3) float32 world joint-head positions (the cmu_mb skeleton).
    fps: float64 scalar.
plus any extra arrays passed as keyword arguments (stored with ``np.asarray``; object
arrays are refused so that the archive loads without pickle).
"""

from __future__ import annotations

import pickle
import zipfile
import zlib
from pathlib import Path

import numpy as np

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.export._checks import check_positive, faces_array, frames_array
from hyperbones.io_utils import atomic_path

NUM_JOINTS = 31  # hyperbones.body.skeleton.NUM_JOINTS (not imported: that package loads Anny)
FRAMES_KEYS = ("garment_vertices", "garment_faces", "body_vertices", "body_faces",
               "joint_positions", "fps")


def _checked_arrays(garment_vertices, garment_faces, body_vertices, body_faces,
                    joint_positions, fps) -> dict[str, np.ndarray]:
    """The contract arrays, validated and converted; raises ParameterError."""
    garment = frames_array("garment_vertices", garment_vertices)
    body = frames_array("body_vertices", body_vertices)
    joints = frames_array("joint_positions", joint_positions)
    if joints.shape[1] != NUM_JOINTS:
        raise ParameterError(
            f"joint_positions must have shape (T,{NUM_JOINTS},3), got {joints.shape}")
    counts = {"garment_vertices": garment.shape[0], "body_vertices": body.shape[0],
              "joint_positions": joints.shape[0]}
    if len(set(counts.values())) > 1:
        listed = ", ".join(f"{k} {v}" for k, v in counts.items())
        raise ParameterError(f"frame counts differ: {listed}")
    return {
        "garment_vertices": garment.astype(np.float32, copy=False),
        "garment_faces": faces_array("garment_faces", garment_faces, garment.shape[1]).astype(np.int32),
        "body_vertices": body.astype(np.float32, copy=False),
        "body_faces": faces_array("body_faces", body_faces, body.shape[1]).astype(np.int32),
        "joint_positions": joints.astype(np.float32, copy=False),
        "fps": np.float64(check_positive("fps", fps)),
    }


def write_frames_npz(
    path: str | Path,
    *,
    garment_vertices,
    garment_faces,
    body_vertices,
    body_faces,
    joint_positions,
    fps: float,
    **extra,
) -> Path:
    """Validate and write ``frames.npz`` (atomically; nothing is written on a ParameterError).

    All positions must share the same frame count T. Returns the path written.
    """
    path = Path(path)
    if path.suffix != ".npz":
        raise ParameterError(f"{path}: the frames output must end in .npz")
    arrays = _checked_arrays(garment_vertices, garment_faces, body_vertices, body_faces,
                             joint_positions, fps)
    for key, value in extra.items():
        array = np.asarray(value)
        if array.dtype.hasobject:
            raise ParameterError(f"extra {key!r} is not a numeric or string array (dtype object)")
        arrays[key] = array
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return path


def read_frames_npz(path: str | Path) -> dict:
    """Read ``frames.npz``: a dict of the contract arrays (``fps`` as a float) plus extras.

    Raises InputFileError when the file is unreadable, lacks a contract key, or its arrays
    do not fit the contract.
    """
    path = Path(path)
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise InputFileError(path, "not an .npz archive (a single .npy array)")
        with loaded as archive:
            data = {key: archive[key] for key in archive.files}
    except FileNotFoundError:
        raise InputFileError(path, "no such file") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, pickle.UnpicklingError, zlib.error,
            NotImplementedError, RuntimeError, MemoryError) as exc:
        # zlib.error: a damaged deflated member; NotImplementedError: an unknown compression method;
        # RuntimeError: a member flagged as encrypted; MemoryError: a header claiming a huge shape.
        raise InputFileError(path, f"not a readable .npz archive ({type(exc).__name__}: {exc})") from None
    missing = [key for key in FRAMES_KEYS if key not in data]
    if missing:
        raise InputFileError(path, f"missing frames.npz keys: {', '.join(missing)}")
    for key in FRAMES_KEYS:  # e.g. a structured array, which even an empty faces array cannot be cast from
        if data[key].dtype.kind not in "iuf":
            raise InputFileError(path, f"{key} has dtype {data[key].dtype}, not a numeric one")
    try:
        with np.errstate(over="ignore"):  # float64 beyond float32's range: refused just below
            checked = _checked_arrays(*(data[key] for key in FRAMES_KEYS))
    except ParameterError as exc:
        raise InputFileError(path, str(exc)) from None
    for key in ("garment_vertices", "body_vertices", "joint_positions"):
        if not np.isfinite(checked[key]).all():  # finite float64 values beyond float32's range
            raise InputFileError(path, f"{key} has values too large for float32")
    data.update(checked)
    data["fps"] = float(checked["fps"])
    return data
