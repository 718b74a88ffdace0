"""Exporters: OBJ sequence, PC2 point cache, USD stage, frames.npz, and atomic writing."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from hyperbones.errors import InputFileError, OutputError, ParameterError
from hyperbones.export import (SceneMesh, read_frames_npz, read_pc2, write_frames_npz,
                               write_obj_sequence, write_pc2, write_usd)
from hyperbones.export import frames as frames_module
from hyperbones.export import obj_sequence as obj_module
from hyperbones.export import pc2 as pc2_module
from hyperbones.export import usd as usd_module


# ---------------------------------------------------------------------------------------
# procedural test meshes

def tube(n_around: int = 6, n_rows: int = 4, n_frames: int = 4):
    """An open cylinder (Z up) that sways over time, with a UV seam where u wraps 1 -> 0.

    Returns vertices (T,V,3) float32, faces (F,3), uvs (U,2), face_uvs (F,3) with
    U = (n_around + 1) * n_rows (the seam column is duplicated in UV space only).
    """
    angles = 2 * np.pi * np.arange(n_around) / n_around
    rows = np.linspace(0.0, 1.0, n_rows)
    ring = np.stack([0.2 * np.cos(angles), 0.2 * np.sin(angles)], axis=1)
    rest = np.concatenate(
        [np.column_stack([ring, np.full(n_around, z)]) for z in rows]).astype(np.float64)
    vid = np.arange(n_rows * n_around).reshape(n_rows, n_around)
    uvid = np.arange(n_rows * (n_around + 1)).reshape(n_rows, n_around + 1)
    faces, face_uvs = [], []
    for r in range(n_rows - 1):
        for a in range(n_around):
            b = (a + 1) % n_around  # vertex index wraps ...
            v00, v01, v10, v11 = vid[r, a], vid[r, b], vid[r + 1, a], vid[r + 1, b]
            t00, t01, t10, t11 = uvid[r, a], uvid[r, a + 1], uvid[r + 1, a], uvid[r + 1, a + 1]  # ... UVs do not
            faces += [(v00, v01, v11), (v00, v11, v10)]
            face_uvs += [(t00, t01, t11), (t00, t11, t10)]
    us, vs = np.meshgrid(np.linspace(0, 1, n_around + 1), np.linspace(0, 1, n_rows))
    uvs = np.column_stack([us.ravel(), vs.ravel()])
    t = np.arange(n_frames)[:, None, None]
    sway = np.zeros((n_frames, 1, 3))
    sway[..., 0] = 0.05 * t[..., 0]
    vertices = (rest[None] + sway * rest[None, :, 2:3] + 0.001 * t).astype(np.float32)
    return vertices, np.array(faces), uvs, np.array(face_uvs)


def parse_obj(path: Path):
    """A tiny OBJ reader: v, vt and triangle f lines (v or v/vt), 0-based indices."""
    v, vt, f, fvt = [], [], [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            v.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vt":
            vt.append([float(x) for x in parts[1:3]])
        elif parts[0] == "f":
            corners = [c.split("/") for c in parts[1:]]
            f.append([int(c[0]) - 1 for c in corners])
            if len(corners[0]) > 1:
                fvt.append([int(c[1]) - 1 for c in corners])
    return np.array(v), np.array(vt), np.array(f), np.array(fvt)


def read_pc2_published_layout(path: Path):
    """PC2 reader written from the published layout, independent of hyperbones' reader."""
    raw = path.read_bytes()
    signature, version, n_points, start, rate, n_samples = struct.unpack("<12siiffi", raw[:32])
    data = np.frombuffer(raw, dtype="<f4", offset=32).reshape(n_samples, n_points, 3)
    return signature, version, n_points, start, rate, n_samples, data


def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


# ---------------------------------------------------------------------------------------
# OBJ sequence

def test_obj_sequence_files_and_round_trip(tmp_path):
    vertices, faces, uvs, face_uvs = tube()
    out = tmp_path / "seq"
    paths = write_obj_sequence(out, vertices, faces, uvs=uvs, face_uvs=face_uvs, name="shirt")
    assert [p.name for p in paths] == [f"shirt_{i:04d}.obj" for i in range(len(vertices))]
    assert leftovers(out) == [p.name for p in paths]
    v, vt, f, fvt = parse_obj(paths[2])
    np.testing.assert_allclose(v, vertices[2], atol=1e-6)
    np.testing.assert_array_equal(f, faces)
    np.testing.assert_allclose(vt, uvs, atol=1e-6)
    np.testing.assert_array_equal(fvt, face_uvs)
    # the seam: some faces use a UV index that differs from their vertex layout
    assert not np.array_equal(fvt, f)


def test_obj_sequence_trimesh_reads_frame(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    vertices, faces, _, _ = tube()
    paths = write_obj_sequence(tmp_path / "seq", vertices, faces)
    mesh = trimesh.load(paths[1], process=False, maintain_order=True)
    np.testing.assert_allclose(mesh.vertices, vertices[1], atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, faces)


def test_obj_sequence_y_up(tmp_path):
    vertices = np.array([[[1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    faces = np.array([[0, 1, 2]])
    (path,) = write_obj_sequence(tmp_path / "y", vertices, faces, up="Y")
    v, _, f, _ = parse_obj(path)
    np.testing.assert_allclose(v[0], [1.0, 3.0, -2.0])
    assert "-0.000000" not in path.read_text()
    np.testing.assert_array_equal(f, faces)
    with pytest.raises(ParameterError):
        write_obj_sequence(tmp_path / "x", vertices, faces, up="X")


def test_obj_sequence_rewrite_removes_stale_frames_only(tmp_path):
    vertices, faces, _, _ = tube(n_frames=5)
    out = tmp_path / "seq"
    write_obj_sequence(out, vertices, faces)
    (out / "notes.txt").write_text("keep me")
    write_obj_sequence(out, vertices[:2], faces)
    assert leftovers(out) == ["garment_0000.obj", "garment_0001.obj", "notes.txt"]


def test_obj_sequence_rejects_bad_input(tmp_path):
    vertices, faces, uvs, face_uvs = tube()
    with pytest.raises(ParameterError):
        write_obj_sequence(tmp_path / "a", vertices[0], faces)  # (V,3): no frame axis
    with pytest.raises(ParameterError):
        write_obj_sequence(tmp_path / "a", vertices, faces + 1000)
    with pytest.raises(ParameterError):
        write_obj_sequence(tmp_path / "a", vertices, faces, face_uvs=face_uvs)  # no uvs
    with pytest.raises(ParameterError):
        write_obj_sequence(tmp_path / "a", vertices, faces, name="../evil")
    assert leftovers(tmp_path) == []


# ---------------------------------------------------------------------------------------
# PC2

def test_pc2_matches_published_layout(tmp_path):
    vertices, _, _, _ = tube(n_frames=5)
    path = write_pc2(tmp_path / "tube.pc2", vertices, fps=30.0, start_frame=10.0)
    signature, version, n_points, start, rate, n_samples, data = read_pc2_published_layout(path)
    assert signature == b"POINTCACHE2\0"
    assert (version, n_points, n_samples) == (1, vertices.shape[1], vertices.shape[0])
    assert (start, rate) == (10.0, 1.0)
    assert path.stat().st_size == 32 + vertices.size * 4
    np.testing.assert_array_equal(data, vertices)

    read, read_start, read_rate = read_pc2(path)
    assert read.dtype == np.float32
    np.testing.assert_array_equal(read, vertices)
    assert (read_start, read_rate) == (10.0, 1.0)


def test_pc2_y_up(tmp_path):
    vertices = np.array([[[1.0, 2.0, 3.0]], [[4.0, 5.0, 6.0]]], dtype=np.float32)
    path = write_pc2(tmp_path / "y.pc2", vertices, up="Y")
    data = read_pc2_published_layout(path)[-1]
    np.testing.assert_array_equal(data[:, 0], [[1.0, 3.0, -2.0], [4.0, 6.0, -5.0]])


def test_read_pc2_rejects_bad_files(tmp_path):
    vertices, _, _, _ = tube()
    good = write_pc2(tmp_path / "good.pc2", vertices).read_bytes()

    truncated = tmp_path / "truncated.pc2"
    truncated.write_bytes(good[:-10])
    with pytest.raises(InputFileError, match="truncated"):
        read_pc2(truncated)

    header_only = tmp_path / "short.pc2"
    header_only.write_bytes(good[:20])
    with pytest.raises(InputFileError, match="truncated"):
        read_pc2(header_only)

    wrong = tmp_path / "wrong.pc2"
    wrong.write_bytes(b"POINTCACHE3\0" + good[12:])
    with pytest.raises(InputFileError, match="signature"):
        read_pc2(wrong)

    with pytest.raises(InputFileError):
        read_pc2(tmp_path / "missing.pc2")


# ---------------------------------------------------------------------------------------
# USD

@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usd"])
def test_usd_stage(tmp_path, suffix):
    from pxr import Usd, UsdGeom

    vertices, faces, uvs, face_uvs = tube(n_frames=5)
    body_vertices, body_faces, _, _ = tube(n_around=8, n_rows=3, n_frames=5)
    static_vertices = vertices[0] + 1.0
    meshes = [
        SceneMesh("garment", vertices, faces, uvs=uvs, face_uvs=face_uvs, display_color=(0.8, 0.1, 0.1)),
        SceneMesh("body", body_vertices, body_faces),
        SceneMesh("floor", static_vertices, faces),
    ]
    path = write_usd(tmp_path / f"scene{suffix}", meshes, fps=24.0)
    assert leftovers(tmp_path) == [path.name]

    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z == "Z"
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetStartTimeCode() == 0 and stage.GetEndTimeCode() == 4
    assert stage.GetTimeCodesPerSecond() == 24.0 and stage.GetFramesPerSecond() == 24.0
    assert stage.GetDefaultPrim().GetPath() == "/Root"
    assert stage.GetPrimAtPath("/Root").IsA(UsdGeom.Xform)

    garment = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/garment"))
    assert garment and UsdGeom.Mesh(stage.GetPrimAtPath("/Root/body"))
    points = garment.GetPointsAttr()
    assert list(points.GetTimeSamples()) == [0.0, 1.0, 2.0, 3.0, 4.0]
    for t in (0, 2, 4):
        np.testing.assert_array_equal(np.asarray(points.Get(t)), vertices[t])
        extent = np.asarray(garment.GetExtentAttr().Get(t))
        np.testing.assert_allclose(extent, [vertices[t].min(0), vertices[t].max(0)])
    body_points = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/body")).GetPointsAttr()
    np.testing.assert_array_equal(np.asarray(body_points.Get(3)), body_vertices[3])

    assert list(garment.GetFaceVertexCountsAttr().Get()) == [3] * len(faces)
    np.testing.assert_array_equal(np.asarray(garment.GetFaceVertexIndicesAttr().Get()), faces.ravel())

    st = UsdGeom.PrimvarsAPI(garment).GetPrimvar("st")
    assert st and st.GetInterpolation() == UsdGeom.Tokens.faceVarying
    np.testing.assert_allclose(np.asarray(st.Get()), uvs, atol=1e-7)
    np.testing.assert_array_equal(np.asarray(st.GetIndices()), face_uvs.ravel())
    np.testing.assert_allclose(np.asarray(st.ComputeFlattened()), uvs[face_uvs.ravel()], atol=1e-7)
    color = UsdGeom.PrimvarsAPI(garment).GetPrimvar("displayColor")
    np.testing.assert_allclose(np.asarray(color.Get()), [[0.8, 0.1, 0.1]], atol=1e-7)

    floor = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/floor")).GetPointsAttr()
    assert floor.GetNumTimeSamples() == 0
    np.testing.assert_array_equal(np.asarray(floor.Get()), static_vertices)


def test_usd_y_up_and_units(tmp_path):
    from pxr import Usd, UsdGeom

    vertices = np.array([[[1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    path = write_usd(tmp_path / "y.usda", [SceneMesh("m", vertices, [[0, 1, 2]])],
                     up_axis="Y", meters_per_unit=0.01)
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == "Y"
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.01)
    points = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/Root/m")).GetPointsAttr().Get(0))
    np.testing.assert_allclose(points[0], [100.0, 300.0, -200.0])


def test_usd_rejects_bad_input(tmp_path):
    vertices, faces, _, _ = tube(n_frames=3)
    with pytest.raises(ParameterError, match="frame counts"):
        write_usd(tmp_path / "a.usda", [SceneMesh("a", vertices, faces), SceneMesh("b", vertices[:2], faces)])
    with pytest.raises(ParameterError, match="identifier"):
        write_usd(tmp_path / "a.usda", [SceneMesh("my mesh", vertices, faces)])
    with pytest.raises(ParameterError, match="named"):
        write_usd(tmp_path / "a.usda", [SceneMesh("a", vertices, faces), SceneMesh("a", vertices, faces)])
    with pytest.raises(ParameterError):
        write_usd(tmp_path / "a.obj", [SceneMesh("a", vertices, faces)])
    assert leftovers(tmp_path) == []


# ---------------------------------------------------------------------------------------
# frames.npz

def frames_inputs(n_frames: int = 4):
    garment, garment_faces, _, _ = tube(n_frames=n_frames)
    body, body_faces, _, _ = tube(n_around=8, n_rows=5, n_frames=n_frames)
    joints = np.random.default_rng(0).normal(size=(n_frames, 31, 3))
    return dict(garment_vertices=garment, garment_faces=garment_faces, body_vertices=body,
                body_faces=body_faces, joint_positions=joints, fps=30)


def test_frames_npz_round_trip(tmp_path):
    inputs = frames_inputs()
    path = write_frames_npz(tmp_path / "frames.npz", **inputs, sim_seconds=np.array([0.1, 0.2]))
    with np.load(path) as raw:
        assert sorted(raw.files) == sorted(["garment_vertices", "garment_faces", "body_vertices",
                                            "body_faces", "joint_positions", "fps", "sim_seconds"])
        assert raw["garment_vertices"].dtype == np.float32
        assert raw["body_vertices"].dtype == np.float32
        assert raw["joint_positions"].dtype == np.float32
    data = read_frames_npz(path)
    for key in ("garment_vertices", "body_vertices", "joint_positions"):
        np.testing.assert_allclose(data[key], inputs[key], rtol=1e-6, atol=1e-7)
        assert data[key].shape == np.shape(inputs[key])
    for key in ("garment_faces", "body_faces"):
        np.testing.assert_array_equal(data[key], inputs[key])
    assert data["fps"] == 30.0 and isinstance(data["fps"], float)
    np.testing.assert_array_equal(data["sim_seconds"], [0.1, 0.2])


def test_frames_npz_rejects_mismatched_frames_and_writes_nothing(tmp_path):
    inputs = frames_inputs()
    inputs["body_vertices"] = inputs["body_vertices"][:3]
    with pytest.raises(ParameterError, match="frame counts"):
        write_frames_npz(tmp_path / "frames.npz", **inputs)
    inputs = frames_inputs()
    inputs["joint_positions"] = inputs["joint_positions"][:, :30]
    with pytest.raises(ParameterError, match="31"):
        write_frames_npz(tmp_path / "frames.npz", **inputs)
    assert leftovers(tmp_path) == []


def test_read_frames_npz_rejects_incomplete_archive(tmp_path):
    path = tmp_path / "frames.npz"
    np.savez(path, garment_vertices=np.zeros((2, 3, 3), np.float32))
    with pytest.raises(InputFileError, match="missing"):
        read_frames_npz(path)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InputFileError):
        read_frames_npz(tmp_path / "junk.npz")


# ---------------------------------------------------------------------------------------
# atomicity: a failure while writing leaves neither the target nor a temporary file

class DiskFull(OSError):
    pass


def half_writing_open(real_open=open):
    """An ``open`` whose file accepts one write and fails on the next (a full disk)."""
    def fake_open(path, mode="r", *args, **kwargs):
        handle = real_open(path, mode, *args, **kwargs)
        writes = []
        original_write = handle.write

        def write(data):
            if writes:
                raise DiskFull(28, "No space left on device")
            writes.append(len(data))
            return original_write(data)

        handle.write = write
        return handle
    return fake_open


def test_pc2_failure_leaves_nothing(tmp_path, monkeypatch):
    vertices, _, _, _ = tube()
    monkeypatch.setattr(pc2_module, "open", half_writing_open(), raising=False)
    with pytest.raises(OutputError, match="No space left on device"):
        write_pc2(tmp_path / "cache.pc2", vertices)
    assert leftovers(tmp_path) == []


def test_frames_failure_keeps_previous_file(tmp_path, monkeypatch):
    path = write_frames_npz(tmp_path / "frames.npz", **frames_inputs())
    before = path.read_bytes()

    def failing_savez(file, **arrays):
        file.write(b"PK partial")
        raise DiskFull(28, "No space left on device")

    monkeypatch.setattr(frames_module.np, "savez", failing_savez)
    with pytest.raises(OutputError, match="No space left on device"):
        write_frames_npz(path, **frames_inputs())
    assert leftovers(tmp_path) == ["frames.npz"]
    assert path.read_bytes() == before


def test_obj_sequence_failure_leaves_nothing(tmp_path, monkeypatch):
    vertices, faces, uvs, face_uvs = tube(n_frames=4)
    calls = []
    real_block = obj_module._vertex_block

    def failing_block(line, points):
        calls.append(1)
        if len(calls) == 3:
            raise DiskFull(28, "No space left on device")
        return real_block(line, points)

    monkeypatch.setattr(obj_module, "_vertex_block", failing_block)
    with pytest.raises(OutputError, match="No space left on device"):
        write_obj_sequence(tmp_path / "seq", vertices, faces, uvs=uvs, face_uvs=face_uvs)
    assert leftovers(tmp_path) == []

    # into an existing folder: the earlier sequence survives untouched
    monkeypatch.setattr(obj_module, "_vertex_block", real_block)
    write_obj_sequence(tmp_path / "seq", vertices[:2], faces)
    before = {p.name: p.read_bytes() for p in (tmp_path / "seq").iterdir()}
    calls.clear()
    monkeypatch.setattr(obj_module, "_vertex_block", failing_block)
    with pytest.raises(OutputError, match="No space left on device"):
        write_obj_sequence(tmp_path / "seq", vertices + 1.0, faces)
    assert {p.name: p.read_bytes() for p in (tmp_path / "seq").iterdir()} == before


def test_usd_failure_leaves_nothing(tmp_path, monkeypatch):
    vertices, faces, _, _ = tube()
    real_define = usd_module._define_mesh

    def failing_define(stage, mesh):
        real_define(stage, mesh)
        if mesh.name == "b":
            raise DiskFull(28, "No space left on device")

    monkeypatch.setattr(usd_module, "_define_mesh", failing_define)
    meshes = [SceneMesh("a", vertices, faces), SceneMesh("b", vertices, faces)]
    for suffix in (".usda", ".usdc"):
        with pytest.raises(OutputError, match="No space left on device"):
            write_usd(tmp_path / f"scene{suffix}", meshes)
    assert leftovers(tmp_path) == []

    target = tmp_path / "scene.usda"
    target.write_text("#usda 1.0\n")
    with pytest.raises(OutputError, match="No space left on device"):
        write_usd(target, meshes)
    assert leftovers(tmp_path) == ["scene.usda"]
    assert target.read_text() == "#usda 1.0\n"
