"""Fuzzing the BVH loaders (``motion.bvh.read_bvh``, ``motion.load.load_motion``) with mutations of
real CMU clips cut to a few dozen frames: each case loads a finite clip / motion or raises the
package's one-line error naming the file."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import strategies as st
from test_fuzz_support import fuzz, loads_or_fails_cleanly, mutations, special_numbers, write_case

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.motion.bvh import read_bvh
from hyperbones.motion.load import load_motion

CMU_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "mocap" / "cmu"
CLIPS = ("16_35", "02_03")
FRAMES = 24


def _cut(path: Path, frames: int = FRAMES) -> bytes:
    """The clip with only its first ``frames`` frames (the header's count changed to match)."""
    lines = path.read_bytes().split(b"\n")
    motion = next(i for i, line in enumerate(lines) if line.strip() == b"MOTION")
    count = next(i for i in range(motion, len(lines)) if lines[i].startswith(b"Frames:"))
    lines[count] = f"Frames: {frames}".encode()
    return b"\n".join(lines[: count + 2 + frames]) + b"\n"


@pytest.fixture(scope="module")
def clips() -> list[bytes]:
    missing = [name for name in CLIPS if not (CMU_DIR / f"{name}.bvh").exists()]
    if missing:
        pytest.skip(f"../shared/data/mocap/cmu lacks {missing}: the shared data folder is absent")
    return [_cut(CMU_DIR / f"{name}.bvh") for name in CLIPS]


@st.composite
def _header_mutation(draw, data: bytes) -> bytes:
    """The 'Frames:' or 'Frame Time:' value replaced (plain mutations seldom hit the header)."""
    label = draw(st.sampled_from([b"Frames:", b"Frame Time:"]))
    value = draw(st.one_of(special_numbers(), st.sampled_from(["1000", "3600", "0.5", "23", "25", "2", "1"])))
    return re.sub(rb"(?m)^" + label + rb"[^\n]*", label + b" " + value.encode(), data, count=1)


@st.composite
def mutated_clip(draw, clips: list[bytes]) -> bytes:
    data = clips[draw(st.integers(0, len(clips) - 1))]
    if draw(st.integers(0, 4)) == 0:
        data = draw(_header_mutation(data))
    return draw(mutations(data))


def test_cut_clips_load(clips, tmp_path):
    """The unmutated cut clips load: the mutations start from valid files."""
    for data in clips:
        clip = read_bvh(write_case(tmp_path / "whole.bvh", data))
        assert clip.num_frames == FRAMES


def test_fuzz_read_bvh(clips, tmp_path):
    def case(data: bytes):
        path = write_case(tmp_path / "clip.bvh", data)
        clip = loads_or_fails_cleanly(lambda: read_bvh(path), path)
        if clip is not None:
            assert clip.local_rotations.shape == (clip.num_frames, 31, 3, 3) and clip.num_frames >= 2
            for values in (clip.local_rotations, clip.root_positions, clip.offsets, *clip.end_sites.values()):
                assert np.isfinite(values).all()
            assert 0 < clip.frame_time < float("inf")

    fuzz(mutated_clip(clips), case)


def test_fuzz_load_motion(body, clips, tmp_path):
    def case(data: bytes):
        path = write_case(tmp_path / "motion.bvh", data)
        motion = loads_or_fails_cleanly(lambda: load_motion(str(path), body, blend_in=2), path)
        if motion is not None:
            assert motion.num_frames >= 1
            assert torch.isfinite(motion.joint_rotations).all() and torch.isfinite(motion.root_translation).all()

    fuzz(mutated_clip(clips), case)


def _edited(data: bytes, pattern: bytes, replacement: bytes) -> bytes:
    return re.sub(pattern, replacement, data, count=1, flags=re.MULTILINE)


@pytest.mark.parametrize("pattern, replacement, phrase", [
    (rb"OFFSET 0\.00000 0\.00000 0\.00000", b"OFFSET 1e999 0 0", "OFFSET of joint Hips is larger than 1e+06"),
    (rb"OFFSET 0\.00000 0\.00000 0\.00000", b"OFFSET 1e308 0 0", "OFFSET of joint Hips is larger than 1e+06"),
    (rb"^Frame Time:.*$", b"Frame Time: 1e38", "outside the 1 to 10000 of motion capture"),
    (rb"^Frame Time:.*$", b"Frame Time: 1e-300", "outside the 1 to 10000 of motion capture"),
])
def test_values_the_fuzzing_found(body, clips, tmp_path, pattern, replacement, phrase):
    """An OFFSET of 1e999 loaded as inf, 1e308 overflowed the kinematics, and a huge Frame Time made
    load_motion resample to ~1e40 frames (OverflowError, or a hang)."""
    path = write_case(tmp_path / "found.bvh", _edited(clips[0], pattern, replacement))
    for load in (lambda: read_bvh(path), lambda: load_motion(str(path), body)):
        with pytest.raises(InputFileError, match=re.escape(phrase)) as error:
            load()
        assert str(error.value).startswith(str(path))


def test_zero_length_legs(clips, tmp_path):
    """Legs without length divided by zero in the retargeting (ZeroDivisionError)."""
    head, motion = clips[0].split(b"MOTION", 1)
    path = write_case(tmp_path / "legless.bvh", re.sub(rb"OFFSET [^\n]*", b"OFFSET 0 0 0", head) + b"MOTION" + motion)
    with pytest.raises(InputFileError, match="the legs have no length"):
        read_bvh(path)


@pytest.mark.parametrize("option, value, phrase", [
    ("fps", float("nan"), "--fps must be positive"), ("fps", 1e9, "--fps must be positive and at most"),
    ("hold", float("nan"), "--hold must be >= 0"), ("hold", float("inf"), "--hold must be >= 0"),
    ("source_fps", float("nan"), "--source-fps must lie in"), ("source_fps", 1e-30, "--source-fps must lie in"),
])
def test_load_motion_options(body, clips, tmp_path, option, value, phrase):
    """NaN or absurd rates and holds passed the old checks (an int(nan) ValueError, or ~1e30 frames)."""
    path = write_case(tmp_path / "clip.bvh", clips[0])
    with pytest.raises(ParameterError, match=re.escape(phrase)):
        load_motion(str(path), body, **{option: value})
