"""Fuzzing the readers of what the package exports (``export.frames.read_frames_npz``,
``export.pc2.read_pc2``) with mutations of files written by their writers: byte-level damage,
and archives re-saved with keys dropped, arrays of other shapes or dtypes, NaN values. Each case
reads data that fits the format's contract or raises the package's one-line error naming the file."""

from __future__ import annotations

import io
import re
import struct

import numpy as np
import pytest
from hypothesis import strategies as st
from test_fuzz_support import fuzz, loads_or_fails_cleanly, mutations, write_case

from hyperbones.errors import InputFileError
from hyperbones.export.frames import FRAMES_KEYS, read_frames_npz, write_frames_npz
from hyperbones.export.pc2 import PC2_HEADER, read_pc2, write_pc2

T, V, VB = 3, 12, 16


def _sequence() -> dict:
    rng = np.random.default_rng(0)
    return dict(garment_vertices=rng.normal(size=(T, V, 3)), garment_faces=rng.integers(0, V, size=(20, 3)),
                body_vertices=rng.normal(size=(T, VB, 3)), body_faces=rng.integers(0, VB, size=(28, 3)),
                joint_positions=rng.normal(size=(T, 31, 3)), fps=30.0)


@pytest.fixture(scope="module")
def frames_file(tmp_path_factory) -> bytes:
    path = write_frames_npz(tmp_path_factory.mktemp("frames") / "frames.npz", **_sequence(),
                            garment_uvs=np.zeros((V, 2), dtype=np.float32))
    return path.read_bytes()


@pytest.fixture(scope="module")
def pc2_file(tmp_path_factory) -> bytes:
    return write_pc2(tmp_path_factory.mktemp("pc2") / "garment.pc2", _sequence()["garment_vertices"]).read_bytes()


# Replacements for one array of the archive.
_ODD_ARRAYS = {
    "nan": lambda a: np.where(np.arange(a.size).reshape(a.shape) == 0, np.nan, a) if a.dtype.kind == "f" else a,
    "inf": lambda a: np.full_like(a, np.inf) if a.dtype.kind == "f" else a,
    "empty": lambda a: a[:0] if a.ndim else np.zeros(0),
    "scalar": lambda a: np.float64(1.0),
    "flat": lambda a: a.reshape(-1),
    "extra axis": lambda a: np.asarray(a)[None],
    "one less column": lambda a: a[..., :-1] if a.ndim else a,
    "strings": lambda a: np.full(a.shape, "x"),
    "bools": lambda a: np.ones(a.shape, dtype=bool),
    "complex": lambda a: a.astype(np.complex64),
    "float16": lambda a: a.astype(np.float16),
    "negative": lambda a: -np.abs(a) - 1,
    "huge": lambda a: np.full(a.shape, 1e300),
    "first frame": lambda a: a[:1] if a.ndim == 3 else a,
    "structured": lambda a: np.zeros(a.shape, dtype=[("x", "f4"), ("y", "i4")]),
}


def _compressed(original: bytes) -> bytes:
    """The same archive written with ``np.savez_compressed`` (deflated members)."""
    with np.load(io.BytesIO(original)) as archive:
        out = io.BytesIO()
        np.savez_compressed(out, **{key: archive[key] for key in archive.files})
    return out.getvalue()


@st.composite
def mutated_frames(draw, original: bytes) -> bytes:
    if draw(st.booleans()):  # damaged bytes of the archive as written, or deflated
        return draw(mutations(draw(st.sampled_from([original, _compressed(original)])), text=False))
    with np.load(io.BytesIO(original)) as archive:
        arrays = {key: archive[key] for key in archive.files}
    for _ in range(draw(st.integers(1, 2))):
        key = draw(st.sampled_from(sorted(arrays)))
        change = draw(st.sampled_from(["drop", "rename", *_ODD_ARRAYS]))
        value = arrays.pop(key)
        if change == "rename":
            arrays[key.upper()] = value
        elif change != "drop":
            try:
                with np.errstate(all="ignore"):  # float16 of large values
                    arrays[key] = _ODD_ARRAYS[change](value)
            except (TypeError, ValueError):  # a change that does not apply to an already changed array
                arrays[key] = value
    out = io.BytesIO()
    (np.savez_compressed if draw(st.booleans()) else np.savez)(out, **arrays)
    return out.getvalue()


def test_fuzz_read_frames_npz(frames_file, tmp_path):
    def case(data: bytes):
        path = write_case(tmp_path / "frames.npz", data)
        frames = loads_or_fails_cleanly(lambda: read_frames_npz(path), path)
        if frames is not None:
            garment, body = frames["garment_vertices"], frames["body_vertices"]
            assert garment.ndim == 3 and garment.shape[2] == 3 and garment.dtype == np.float32
            assert body.shape[0] == garment.shape[0] == frames["joint_positions"].shape[0]
            assert frames["joint_positions"].shape[1:] == (31, 3)
            for key in ("garment_vertices", "body_vertices", "joint_positions"):
                assert np.isfinite(frames[key]).all()
            for faces, count in (("garment_faces", garment.shape[1]), ("body_faces", body.shape[1])):
                assert frames[faces].shape[1:] == (3,) and (frames[faces] >= 0).all() and (frames[faces] < count).all()
            assert isinstance(frames["fps"], float) and 0 < frames["fps"] < float("inf")
            assert set(FRAMES_KEYS) <= set(frames)

    fuzz(mutated_frames(frames_file), case)


@st.composite
def mutated_pc2(draw, original: bytes) -> bytes:
    if draw(st.booleans()):
        return draw(mutations(original, text=False))
    signature, version, points, start, rate, samples = PC2_HEADER.unpack(original[:PC2_HEADER.size])
    field = draw(st.sampled_from(["signature", "version", "points", "start", "rate", "samples", "coordinate"]))
    ints = st.sampled_from([0, -1, 1, 2, V - 1, V + 1, 2**31 - 1, -2**31, T * V])
    floats = st.sampled_from([float("nan"), float("inf"), -float("inf"), 0.0, -1.0, 1e38, -3.4e38, 1e-45])
    if field == "signature":
        signature = draw(st.sampled_from([b"POINTCACHE2 ", b"POINTCACHE1\0", b"\0" * 12, b"pointcache2\0"]))
    elif field == "version":
        version = draw(ints)
    elif field == "points":
        points = draw(ints)
    elif field == "samples":
        samples = draw(ints)
    elif field == "start":
        start = draw(floats)
    elif field == "rate":
        rate = draw(floats)
    header = PC2_HEADER.pack(signature, version, points, start, rate, samples)
    body = bytearray(original[PC2_HEADER.size:])
    if field == "coordinate":
        at = 4 * draw(st.integers(0, len(body) // 4 - 1))
        body[at:at + 4] = struct.pack("<f", draw(floats))
    return header + bytes(body)


def test_fuzz_read_pc2(pc2_file, tmp_path):
    def case(data: bytes):
        path = write_case(tmp_path / "garment.pc2", data)
        read = loads_or_fails_cleanly(lambda: read_pc2(path), path)
        if read is not None:
            vertices, start, rate = read
            assert vertices.ndim == 3 and vertices.shape[2] == 3 and np.isfinite(vertices).all()
            assert np.isfinite(start) and 0 < rate < float("inf")

    fuzz(mutated_pc2(pc2_file), case)


def test_unmutated_files_read(frames_file, pc2_file, tmp_path):
    frames = read_frames_npz(write_case(tmp_path / "frames.npz", frames_file))
    vertices, start, rate = read_pc2(write_case(tmp_path / "garment.pc2", pc2_file))
    np.testing.assert_allclose(vertices, frames["garment_vertices"])
    assert (start, rate) == (0.0, 1.0)
    with pytest.raises(InputFileError, match="no such file"):
        read_frames_npz(tmp_path / "missing.npz")


def _flag_first_member(data: bytes, flag: int) -> bytes:
    """The archive with general-purpose flag bits set on its first local and central headers."""
    out = bytearray(data)
    for signature, offset in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        at = out.find(signature) + offset
        out[at:at + 2] = (int.from_bytes(out[at:at + 2], "little") | flag).to_bytes(2, "little")
    return bytes(out)


def _with(original: bytes, **arrays) -> bytes:
    with np.load(io.BytesIO(original)) as archive:
        values = {key: archive[key] for key in archive.files} | arrays
    out = io.BytesIO()
    np.savez(out, **values)
    return out.getvalue()


@pytest.mark.parametrize("make, phrase", [
    (lambda data: _with(data, garment_vertices=np.full((T, V, 3), 1e300)), "too large for float32"),
    (lambda data: _with(data, body_faces=np.zeros((0, 3), dtype=[("x", "f4")])), "body_faces has dtype"),
    (lambda data: _compressed(data)[:60] + b"\xff" * 40 + _compressed(data)[100:], "not a readable .npz archive"),
    (lambda data: _flag_first_member(data, 0x1), "not a readable .npz archive"),  # "encrypted"
])
def test_frames_the_fuzzing_found(frames_file, tmp_path, make, phrase):
    """Loaded as inf, or raised TypeError / zlib.error / RuntimeError, before."""
    path = write_case(tmp_path / "found.npz", make(frames_file))
    with pytest.raises(InputFileError, match=phrase) as error:
        read_frames_npz(path)
    assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)


@pytest.mark.parametrize("at, value, phrase", [
    (20, float("nan"), "corrupt PC2 header"), (24, 0.0, "corrupt PC2 header"), (24, float("inf"), "corrupt PC2 header"),
    (32 + 4 * 7, float("nan"), "NaN or infinite coordinates (first at sample 0, point 2)"),
])
def test_pc2_the_fuzzing_found(pc2_file, tmp_path, at, value, phrase):
    """A NaN start frame, a zero sample rate and NaN coordinates were read silently."""
    data = pc2_file[:at] + struct.pack("<f", value) + pc2_file[at + 4:]
    with pytest.raises(InputFileError, match=re.escape(phrase)):
        read_pc2(write_case(tmp_path / "found.pc2", data))
