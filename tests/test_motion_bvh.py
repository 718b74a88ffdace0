"""Tests for the strict CMU BVH reader and its forward kinematics."""

from __future__ import annotations

import csv
import dataclasses
import re
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hyperbones.errors import InputFileError
from hyperbones.motion.bvh import (
    CMU_JOINT_NAMES,
    CMU_JOINT_PARENTS,
    BvhClip,
    bvh_forward_kinematics,
    read_bvh,
)

SHARED = Path(__file__).resolve().parents[2] / "shared"
CMU_DIR = SHARED / "data" / "mocap" / "cmu"
CMU_CLIPS = [
    "01_01", "02_01", "02_03", "05_06", "111_10", "143_06",
    "16_07", "16_21", "16_27", "16_35", "69_53", "74_06",
]  # fmt: skip
ZYX = ["Zrotation", "Yrotation", "Xrotation"]
ROOT_CHANNELS = ["Xposition", "Yposition", "Zposition", *ZYX]
J = CMU_JOINT_NAMES.index  # canonical index of a joint name
FILE_FINGER_NAMES = {"LeftHandFinger1": "LeftHandIndex1", "RightHandFinger1": "RightHandIndex1"}


def cmu_joints(without: str | None = None) -> list[tuple[str, str | None]]:
    """(name as a mirror writes it, parent name) for the CMU skeleton, root first."""
    return [
        (FILE_FINGER_NAMES.get(n, n), None if p < 0 else CMU_JOINT_NAMES[p])
        for n, p in zip(CMU_JOINT_NAMES, CMU_JOINT_PARENTS)
        if n != without
    ]


# --------------------------------------------------------------------------- synthetic files


def _default_offset(j: int) -> tuple[float, float, float]:
    # Distinct, non-zero offsets so that a joint read into the wrong slot shows.
    return (0.5 + j % 3, -1.0 - j % 5 * 0.25, 0.125 * (j % 4))


def make_bvh(
    num_frames: int = 5,
    *,
    values: dict[str, np.ndarray] | None = None,
    channels: dict[str, list[str]] | None = None,
    offsets: dict[str, tuple[float, float, float]] | None = None,
    joints: list[tuple[str, str | None]] | None = None,
    frame_time: str = ".0083333",
    newline: str = "\n",
    seed: int | None = 0,
) -> str:
    """A BVH text in the CMU layout (or `joints`: (name, parent name) pairs, root first).

    Children are written in reverse canonical order, so the file's joint order is not the
    canonical one. `values` gives a joint's channel values (num_frames, its channel count);
    other joints get small random angles (or zeros when seed is None).
    """
    joints = joints or cmu_joints()
    channels, offsets, values = channels or {}, offsets or {}, values or {}
    children = {name: [c for c, p in joints if p == name][::-1] for name, _ in joints}
    rng = np.random.default_rng(seed)
    lines, columns = ["HIERARCHY"], []

    def write(name: str, depth: int) -> None:
        tab = "\t" * depth
        is_root = depth == 0
        chans = channels.get(name, ROOT_CHANNELS if is_root else ZYX)
        offset = offsets.get(name, _default_offset(len(columns)))
        lines.extend([f"{tab}{'ROOT' if is_root else 'JOINT'} {name}", f"{tab}{{"])
        lines.append(f"{tab}\tOFFSET {offset[0]:.6f} {offset[1]:.6f} {offset[2]:.6f}")
        lines.append(f"{tab}\tCHANNELS {len(chans)} {' '.join(chans)}")
        if name in values:
            columns.append(np.asarray(values[name], dtype=float).reshape(num_frames, len(chans)))
        elif seed is None:
            columns.append(np.zeros((num_frames, len(chans))))
        else:
            columns.append(rng.uniform(-30, 30, (num_frames, len(chans))))
        for child in children[name]:
            write(child, depth + 1)
        if not children[name]:
            end_site = ["End Site", "{", "\tOFFSET 0.0 0.5 0.0", "}"]
            lines.extend(f"{tab}\t{line}" for line in end_site)
        lines.append(f"{tab}}}")

    write(joints[0][0], 0)
    lines += ["MOTION", f"Frames: {num_frames}", f"Frame Time: {frame_time}"]
    data = np.concatenate(columns, axis=1)
    lines += [" ".join(f"{v:.4f}" for v in row) for row in data]
    return newline.join(lines) + newline


def frame_line_number(text: str, frame: int) -> int:
    """1-based line number of a frame's data line in a file from make_bvh."""
    lines = text.split("\n")
    return next(i for i, line in enumerate(lines) if line.startswith("Frame Time:")) + 2 + frame


def write(tmp_path: Path, text: str | bytes, name: str = "clip.bvh") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


def cumulative_offsets(clip: BvhClip) -> np.ndarray:
    out = np.zeros((31, 3))
    for j, p in enumerate(clip.parents):
        out[j] = clip.offsets[j] + (out[p] if p >= 0 else 0)
    return out


# --------------------------------------------------------------------------- synthetic: valid


def test_synthetic_clip_is_reordered_to_canonical(tmp_path):
    text = make_bvh()
    clip = read_bvh(write(tmp_path, text))
    assert clip.joint_names == CMU_JOINT_NAMES
    assert clip.parents.tolist() == CMU_JOINT_PARENTS
    assert clip.num_frames == 5 and clip.local_rotations.shape == (5, 31, 3, 3)
    assert clip.fps == pytest.approx(120.0, rel=1e-4)
    # The file is written in another order; each offset must land under its own name.
    file_order = re.findall(r"(?:ROOT|JOINT) (\S+)", text)
    assert file_order != CMU_JOINT_NAMES
    for k, name in enumerate(file_order):
        canonical = name.replace("Index1", "Finger1")
        j = CMU_JOINT_NAMES.index(canonical)
        np.testing.assert_allclose(clip.offsets[j], _default_offset(k), atol=1e-6)
    leaves = {CMU_JOINT_NAMES[j] for j in range(31) if j not in CMU_JOINT_PARENTS}
    assert set(clip.end_sites) == leaves
    np.testing.assert_allclose(clip.end_sites["Head"], [0, 0.5, 0])


def test_number_spellings_crlf_and_trailing_blank_lines(tmp_path):
    root = np.array([[0.5, -0.0, 1e-3, 0, 0, 0], [-0.25, 2.5, 3.0, 0, 0, 0]])
    text = make_bvh(2, values={"Hips": root}, seed=None)
    for column, spelling in enumerate([".5", "-0.00000", "1e-3", "+0.0E0", "-0."]):
        text = _edit_value(text, 0, column, spelling)
    text = text.replace("Frame Time: .0083333", "Frame Time:\t.0083333")
    clip = read_bvh(write(tmp_path, text.replace("\n", "\r\n") + "\n  \n"))
    np.testing.assert_allclose(clip.root_positions, root[:, :3])
    assert clip.frame_time == pytest.approx(0.0083333)
    np.testing.assert_allclose(clip.local_rotations[:, 0], np.broadcast_to(np.eye(3), (2, 3, 3)))


def test_both_finger_spellings_are_normalised(tmp_path):
    for left, right in [("LeftHandIndex1", "RightHandIndex1"), ("LFingers", "RFingers")]:
        text = make_bvh().replace("LeftHandIndex1", left).replace("RightHandIndex1", right)
        assert f"JOINT {left}" in text and f"JOINT {right}" in text
        clip = read_bvh(write(tmp_path, text))
        assert clip.joint_names[15] == "LeftHandFinger1"
        assert clip.joint_names[25] == "RightHandFinger1"
        assert "LeftHandFinger1" in clip.end_sites


def test_zero_rotations_give_cumulative_offsets(tmp_path):
    root = np.zeros((3, 6))
    root[:, :3] = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [-1.0, 0.0, 7.5]]
    clip = read_bvh(write(tmp_path, make_bvh(3, values={"Hips": root}, seed=None)))
    positions, rotations = bvh_forward_kinematics(clip)
    expected = cumulative_offsets(clip)[None] + root[:, None, :3]
    np.testing.assert_allclose(positions, expected, atol=1e-12)
    np.testing.assert_allclose(rotations, np.broadcast_to(np.eye(3), rotations.shape), atol=1e-12)


def test_zyx_channel_order_rotates_child_offset(tmp_path):
    # LeftArm's channels are Z Y X; Z = 90 turns its child's offset +X into +Y (Y up).
    angles = {"LeftArm": [[0, 0, 0], [90, 0, 0]]}
    text = make_bvh(2, values=angles, offsets={"LeftForeArm": (1, 0, 0)}, seed=None)
    positions, _ = bvh_forward_kinematics(read_bvh(write(tmp_path, text)))
    bone = positions[:, J("LeftForeArm")] - positions[:, J("LeftArm")]
    np.testing.assert_allclose(bone, [[1, 0, 0], [0, 1, 0]], atol=1e-12)


def test_declared_xyz_channel_order_is_honoured(tmp_path):
    xyz = ["Xrotation", "Yrotation", "Zrotation"]
    angles = [[90, 90, 0], [10, -20, 35]]
    text = make_bvh(
        2,
        values={"LeftArm": angles},
        channels={"LeftArm": xyz},
        offsets={"LeftForeArm": (1, 0, 0)},
        seed=None,
    )
    clip = read_bvh(write(tmp_path, text))
    arm, forearm = J("LeftArm"), J("LeftForeArm")
    # Rx(90) @ Ry(90) takes +X to +Y; the reverse product would give -Z.
    positions, _ = bvh_forward_kinematics(clip)
    np.testing.assert_allclose(positions[0, forearm] - positions[0, arm], [0, 1, 0], atol=1e-12)
    # Uppercase 'XYZ' in scipy is intrinsic: Rx @ Ry @ Rz.
    expected = Rotation.from_euler("XYZ", angles, degrees=True).as_matrix()
    np.testing.assert_allclose(clip.local_rotations[:, arm], expected, atol=1e-12)


def test_root_rotation_and_position_channels_in_another_order(tmp_path):
    chans = ["Yrotation", "Zposition", "Xrotation", "Xposition", "Zrotation", "Yposition"]
    values = [[30, 3, -20, 1, 45, 2], [0, 6, 0, 4, 0, 5]]
    text = make_bvh(2, values={"Hips": values}, channels={"Hips": chans}, seed=None)
    clip = read_bvh(write(tmp_path, text))
    np.testing.assert_allclose(clip.root_positions, [[1, 2, 3], [4, 5, 6]])
    expected = Rotation.from_euler("YXZ", [[30, -20, 45], [0, 0, 0]], degrees=True).as_matrix()
    np.testing.assert_allclose(clip.local_rotations[:, 0], expected, atol=1e-12)


# --------------------------------------------------------------------------- synthetic: malformed


def _set_line(text: str, number: int, new: str) -> str:
    lines = text.split("\n")
    lines[number - 1] = new
    return "\n".join(lines)


def _edit_value(text: str, frame: int, column: int, token: str) -> str:
    number = frame_line_number(text, frame)
    tokens = text.split("\n")[number - 1].split()
    tokens[column] = token
    return _set_line(text, number, " ".join(tokens))


def _case_empty(t):
    return "", ["empty file"]


def _case_blank(t):
    return "  \n\n\t\n", ["empty file"]


def _case_not_bvh(t):
    return "hello world\n", ["no HIERARCHY section", "line 1", "'hello world'"]


def _case_not_utf8(t):
    return b"HIERARCHY\nROOT Hips\xff\n", ["not UTF-8 text", "0xff"]


def _case_no_motion(t):
    return t[: t.index("MOTION")], ["no MOTION section"]


def _case_other_layout(t):
    joints = [("Hips", None), ("Chest", "Hips"), ("Head", "Chest")]
    phrases = ["missing joints LHipJoint, LeftUpLeg", "RightToeBase; extra joints Chest$"]
    return make_bvh(joints=joints), phrases


def _case_one_joint_missing(t):
    return make_bvh(joints=cmu_joints(without="LThumb")), ["skeleton: missing joints LThumb$"]


def _case_wrong_parent(t):
    # Move LeftToeBase from under LeftFoot to under Hips by renaming two joints' roles.
    swapped = t.replace("JOINT LeftToeBase", "JOINT @tmp")
    swapped = swapped.replace("JOINT LHipJoint", "JOINT LeftToeBase").replace("@tmp", "LHipJoint")
    return swapped, ["joint LHipJoint has parent LeftFoot, expected Hips"]


def _case_truncated_hierarchy(t):
    phrases = ["truncated hierarchy", "still open", "no MOTION section"]
    return t[: t.index("JOINT LeftForeArm")], phrases


def _case_missing_close_brace(t):
    number = t.split("\n").index("}") + 1  # the root's closing brace
    phrases = ["MOTION reached with 1 block(s) still open", "unbalanced braces"]
    return _set_line(t, number, ""), phrases


def _case_extra_close_brace(t):
    phrase = "unexpected '}' after the ROOT joint's closing"
    return t.replace("\n}\nMOTION", "\n}\n}\nMOTION"), [phrase]


def _case_truncated_data(t):
    number = frame_line_number(t, 3)
    cut = "\n".join(t.split("\n")[:number])[:-300]  # mid-way through frame 3's line
    last = f"its last line, {number}, has"
    return cut, ["header says 5 frames but the file has 4 (truncated?", last, "of 96 values)"]


def _case_fewer_frames(t):
    return t.replace("Frames: 5", "Frames: 6"), ["header says 6 frames but the file has 5"]


def _case_more_frames(t):
    return t.replace("Frames: 5", "Frames: 3"), ["header says 3 frames but the file has 5"]


def _case_wrong_value_count(t):
    number = frame_line_number(t, 2)
    line = t.split("\n")[number - 1]
    phrase = f"line {number}: frame 2 has 97 values, expected 96"
    return _set_line(t, number, line + " 1.0"), [phrase]


def _case_blank_frame_line(t):
    number = frame_line_number(t, 1)
    return _set_line(t, number, ""), [f"line {number}: frame 1 has 0 values, expected 96"]


def _case_non_numeric(t):
    number = frame_line_number(t, 3)
    return _edit_value(t, 3, 7, "abc"), [f"line {number}: frame 3 value 8 is not a number: 'abc'"]


def _case_comma_decimal(t):
    return _edit_value(t, 0, 4, "1,5"), ["frame 0 value 5 is not a number: '1,5'"]


def _case_nan(t):
    number = frame_line_number(t, 1)
    return _edit_value(t, 1, 20, "NaN"), [f"line {number}: frame 1 value 21 is non-finite: 'NaN'"]


def _case_overflow(t):
    return _edit_value(t, 4, 0, "1e999"), ["frame 4 value 1 is non-finite: '1e999'"]


def _case_frame_time_zero(t):
    phrases = ["'Frame Time:' must be a positive number", "found '0'"]
    return t.replace("Frame Time: .0083333", "Frame Time: 0"), phrases


def _case_frame_time_text(t):
    phrases = ["'Frame Time:' must be a positive number", "found 'fast'"]
    return t.replace("Frame Time: .0083333", "Frame Time: fast"), phrases


def _case_frame_time_missing(t):
    return t.replace("Frame Time: .0083333\n", ""), ["expected 'Frame Time: <number>'"]


def _case_frames_malformed(t):
    return t.replace("Frames: 5", "Frames: five"), ["'Frames:' needs a whole number, found 'five'"]


def _case_frames_missing(t):
    phrase = "expected 'Frames: <number>', found 'Frame Time: .0083333'"
    return t.replace("Frames: 5\n", ""), [phrase]


def _case_single_frame(t):
    return make_bvh(1), ["only 1 frame(s)", "T-pose"]


def _case_unknown_channel(t):
    number = t.split("\n").index("\t\t\t\tCHANNELS 3 Zrotation Yrotation Xrotation") + 1
    return _set_line(t, number, "\t\t\t\tCHANNELS 3 Zrotation Wrotation Xrotation"), [
        f"line {number}: unknown channel name 'Wrotation'"
    ]


def _case_channel_count(t):
    phrase = "malformed CHANNELS of joint RHipJoint: the count '4' does not match the 3 channel"
    return t.replace("CHANNELS 3 Z", "CHANNELS 4 Z", 1), [phrase]


def _case_root_without_positions(t):
    return t.replace("CHANNELS 6 Xposition Yposition Zposition", "CHANNELS 3"), [
        "root joint Hips needs the channels Xposition Yposition Zposition Xrotation",
        "found Zrotation Yrotation Xrotation",
    ]


def _case_repeated_axis(t):
    phrase = "joint RHipJoint needs the channels Xrotation Yrotation Zrotation once each"
    zyz = "CHANNELS 3 Zrotation Yrotation Zrotation"
    return t.replace("CHANNELS 3 Zrotation Yrotation Xrotation", zyz, 1), [phrase]


def _case_malformed_offset(t):
    return t.replace("OFFSET", "OFFSET 1.0", 2).replace("OFFSET 1.0", "OFFSET", 1), [
        "malformed OFFSET of joint RHipJoint: expected 3 numbers"
    ]


def _case_duplicate_joint(t):
    # Both spellings of the finger joint: they mean the same joint.
    twice = t.replace("JOINT LeftHandIndex1", "JOINT LFingers")
    twice = twice.replace("JOINT LThumb", "JOINT LeftHandIndex1")
    return twice, ["joint LeftHandFinger1 is declared twice (first on line"]


MALFORMED = {name[len("_case_") :]: f for name, f in globals().items() if name.startswith("_case_")}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_file_raises_one_line_error(tmp_path, case):
    content, phrases = MALFORMED[case](make_bvh())
    path = write(tmp_path, content, name=f"bad_{case}.bvh")
    with pytest.raises(InputFileError) as info:
        read_bvh(path)
    message = str(info.value)
    assert "\n" not in message and "\r" not in message
    assert message.startswith(f"{path}: ") and f"bad_{case}.bvh" in message
    for phrase in phrases:  # a trailing '$' means the message ends there
        found = message.endswith(phrase[:-1]) if phrase.endswith("$") else phrase in message
        assert found, message
    assert info.value.__cause__ is None  # no raw ValueError/IndexError behind it


def test_nonexistent_path(tmp_path):
    with pytest.raises(InputFileError, match=r"nothere\.bvh: file not found$"):
        read_bvh(tmp_path / "nothere.bvh")


def test_directory_path(tmp_path):
    with pytest.raises(InputFileError, match="cannot read the file"):
        read_bvh(tmp_path)


# --------------------------------------------------------------------------- real CMU data


@pytest.fixture(scope="module")
def cmu_dir() -> Path:
    if not CMU_DIR.is_dir():
        pytest.skip(f"../shared/data not found: {CMU_DIR} is absent")
    return CMU_DIR


@lru_cache(maxsize=None)
def _read(path: Path) -> BvhClip:
    return read_bvh(path)


def _manifest(cmu_dir: Path) -> dict[str, dict[str, str]]:
    with open(cmu_dir / "MANIFEST.tsv", newline="") as f:
        return {row["file"]: row for row in csv.DictReader(f, delimiter="\t")}


FINGER_SPELLINGS = {
    "LFingers": "LeftHandFinger1", "LeftHandIndex1": "LeftHandFinger1",
    "RFingers": "RightHandFinger1", "RightHandIndex1": "RightHandFinger1",
}  # fmt: skip


def _file_joints(text: str) -> list[tuple[str, np.ndarray]]:
    """(name as written, OFFSET) for each ROOT/JOINT in file order: an independent mini-parse."""
    found = re.findall(r"(?:ROOT|JOINT)\s+(\S+)\s*\{\s*OFFSET\s+(\S+)\s+(\S+)\s+(\S+)", text)
    return [(name, np.array([float(x), float(y), float(z)])) for name, x, y, z in found]


def test_manifest_lists_the_clips(cmu_dir):
    assert sorted(_manifest(cmu_dir)) == sorted(f"{c}.bvh" for c in CMU_CLIPS)


@pytest.mark.parametrize("name", CMU_CLIPS)
def test_cmu_clip_parses(cmu_dir, name):
    path = cmu_dir / f"{name}.bvh"
    clip = _read(path)
    text = path.read_text()
    header_frames = int(re.search(r"Frames:\s*(\d+)", text).group(1))
    assert clip.num_frames == header_frames == int(_manifest(cmu_dir)[path.name]["frames_in_file"])
    assert clip.fps == pytest.approx(float(_manifest(cmu_dir)[path.name]["header_fps"]), rel=1e-3)
    assert clip.joint_names == CMU_JOINT_NAMES
    assert clip.parents.tolist() == CMU_JOINT_PARENTS
    assert clip.offsets.shape == (31, 3) and clip.root_positions.shape == (clip.num_frames, 3)
    assert clip.local_rotations.shape == (clip.num_frames, 31, 3, 3)
    # Either finger spelling is in the file; only the canonical one comes out.
    assert ("LFingers" in text) != ("LeftHandIndex1" in text)
    assert "LeftHandFinger1" in clip.end_sites and "RightHandFinger1" in clip.end_sites
    rotations = clip.local_rotations
    identity = np.broadcast_to(np.eye(3), rotations.shape)
    np.testing.assert_allclose(rotations @ rotations.swapaxes(-1, -2), identity, atol=1e-12)


@pytest.mark.parametrize("name", ["01_01", "02_01", "16_21"])
def test_cmu_joint_order_is_canonical(cmu_dir, name):
    path = cmu_dir / f"{name}.bvh"
    clip = _read(path)
    text = path.read_text()
    declared = _file_joints(text)
    assert len(declared) == 31
    assert [n for n, _ in declared] != CMU_JOINT_NAMES  # so the reader really had to reorder
    # Each joint's OFFSET and rotation must be the ones written under its name in the file.
    motion = text.split("MOTION", 1)[1].split("\n")
    data = np.array([line.split() for line in motion[3:] if line.strip()], dtype=float)
    column = 6
    for k, (written, offset) in enumerate(declared):
        j = J(FINGER_SPELLINGS.get(written, written))
        np.testing.assert_array_equal(clip.offsets[j], offset)
        angles = data[:, 3:6] if k == 0 else data[:, column : column + 3]
        column += 3 * (k > 0)
        expected = Rotation.from_euler("ZYX", angles, degrees=True).as_matrix()  # Rz @ Ry @ Rx
        np.testing.assert_allclose(clip.local_rotations[:, j], expected, atol=1e-12)
    np.testing.assert_array_equal(clip.root_positions, data[:, :3])


@pytest.mark.parametrize("name", ["01_01", "02_01", "16_21", "69_53"])
def test_cmu_bone_lengths_are_constant(cmu_dir, name):
    clip = _read(cmu_dir / f"{name}.bvh")
    positions, rotations = bvh_forward_kinematics(clip)
    for j, p in enumerate(CMU_JOINT_PARENTS[1:], start=1):
        length = np.linalg.norm(positions[:, j] - positions[:, p], axis=-1)
        expected = np.linalg.norm(clip.offsets[j])
        np.testing.assert_allclose(length, expected, rtol=1e-9, atol=1e-9 * max(expected, 1.0))
    np.testing.assert_allclose(np.linalg.det(rotations), 1.0, atol=1e-9)


@pytest.mark.parametrize("name", ["02_01", "16_21"])
def test_cmu_walk_is_plausible(cmu_dir, name):
    clip = _read(cmu_dir / f"{name}.bvh")
    positions, _ = bvh_forward_kinematics(clip)
    y = positions[1:, :, 1]  # frame 0 is the added T-pose
    hips, head = y[:, J("Hips")], y[:, J("Head")]
    feet = y[:, [J("LeftFoot"), J("RightFoot")]]
    assert hips.min() > 14 and hips.max() < 20
    assert (feet < hips[:, None]).all() and (head > hips).all()
    assert feet.min() > -1 and feet.min() < 3  # the ankles come near the ground
    # A walk travels: at least a few body widths across the floor (X-Z plane).
    travel = positions[-1, 0, [0, 2]] - positions[1, 0, [0, 2]]
    assert np.linalg.norm(travel) > 20


def test_cmu_zero_pose_matches_cumulative_offsets(cmu_dir):
    clip = _read(cmu_dir / "02_01.bvh")
    zero = dataclasses.replace(
        clip,
        root_positions=np.zeros((2, 3)),
        local_rotations=np.broadcast_to(np.eye(3), (2, 31, 3, 3)).copy(),
    )
    positions, _ = bvh_forward_kinematics(zero)
    expected = np.broadcast_to(cumulative_offsets(clip), (2, 31, 3))
    np.testing.assert_allclose(positions, expected, atol=1e-12)
    # The T-pose: left-side joints have +X offsets, right-side ones -X; the head is above the hips.
    assert positions[0, J("LeftHand"), 0] > 0 > positions[0, J("RightHand"), 0]
    assert positions[0, J("Head"), 1] > positions[0, J("Hips"), 1]


def test_cmu_long_clip_is_read_whole(cmu_dir):
    # How long the parse takes is a benchmark's question, not a test's (no timing asserted here).
    clip = _read(cmu_dir / "01_01.bvh")
    assert clip.num_frames == 2752 and clip.local_rotations.shape[0] == 2752
