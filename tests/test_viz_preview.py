"""Tests for the headless preview renderer (hyperbones.viz)."""

from __future__ import annotations

import imageio.v2 as imageio
import numpy as np
import pytest
from PIL import Image

from hyperbones.errors import ParameterError
from hyperbones.viz import MeshSequence, preview, render_frame, render_preview
from hyperbones.viz.camera import Camera, orbit_eye, project

SIZE = 96
FRONT = Camera(eye=np.array([0.0, -3.0, 1.0]), target=np.array([0.0, 0.0, 1.0]))  # looks along +Y


def _triangle(y: float, half: float = 0.4) -> np.ndarray:
    """(1, 3, 3) one frame of a triangle in the plane y = const, centred on (0, y, 1)."""
    return np.array([[[-half, y, 1.0 - half], [half, y, 1.0 - half], [0.0, y, 1.0 + half]]])


def _pixel(world_point) -> tuple[int, int]:
    """(row, col) of the pixel containing a world point seen through FRONT."""
    xy, depth = project(FRONT, np.array([world_point], float), SIZE, SIZE)
    assert depth[0] > 0
    return int(xy[0, 1]), int(xy[0, 0])


def _sphere(n_lat: int = 12, n_lon: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """A small UV sphere of radius 0.3: (V, 3) vertices, (F, 3) faces."""
    theta = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3)
    verts = 0.3 * np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]])
    idx = lambda i, j: 1 + i * n_lon + j % n_lon  # noqa: E731
    faces = [[0, idx(0, j), idx(0, j + 1)] for j in range(n_lon)]
    for i in range(n_lat - 2):
        for j in range(n_lon):
            faces += [[idx(i, j), idx(i + 1, j), idx(i, j + 1)], [idx(i, j + 1), idx(i + 1, j), idx(i + 1, j + 1)]]
    last = len(verts) - 1
    faces += [[last, idx(n_lat - 2, j + 1), idx(n_lat - 2, j)] for j in range(n_lon)]
    return verts, np.array(faces)


def _moving_sphere(n_frames: int = 20) -> MeshSequence:
    """A sphere rolling along +X above the floor, (T, V, 3)."""
    verts, faces = _sphere()
    offsets = np.zeros((n_frames, 1, 3))
    offsets[:, 0, 0] = np.linspace(0.0, 1.5, n_frames)
    offsets[:, 0, 2] = 0.3
    return MeshSequence(verts[None] + offsets, faces, (0.2, 0.5, 0.9), "sphere")


def test_single_triangle_covers_expected_pixels():
    tri = MeshSequence(_triangle(0.0), [[0, 1, 2]], (1.0, 0.0, 0.0), "tri")
    image = render_frame([tri], 0, FRONT, SIZE, ground=False)
    background = preview._background(SIZE)
    inside, outside = _pixel((0.0, 0.0, 0.9)), _pixel((0.8, 0.0, 1.0))
    assert image[inside][0] > 60 and image[inside][1] == 0 and image[inside][2] == 0
    assert np.array_equal(image[outside], background[outside])
    # Both sides are drawn and lit alike: reversing the winding changes nothing.
    flipped = MeshSequence(_triangle(0.0), [[0, 2, 1]], (1.0, 0.0, 0.0), "tri", smooth=False)
    assert np.array_equal(render_frame([flipped], 0, FRONT, SIZE, ground=False), image)


def test_zbuffer_keeps_nearer_triangle_in_either_order():
    near = MeshSequence(_triangle(-0.5), [[0, 1, 2]], (1.0, 0.0, 0.0), "near")
    far = MeshSequence(_triangle(0.5, half=0.8), [[0, 1, 2]], (0.0, 0.0, 1.0), "far")
    centre, far_only = _pixel((0.0, 0.0, 0.9)), _pixel((0.0, 0.5, 0.35))
    for order in ([near, far], [far, near]):
        image = render_frame(order, 0, FRONT, SIZE, ground=False)
        assert image[centre][0] > 60 and image[centre][2] == 0
        assert image[far_only][2] > 60 and image[far_only][0] == 0


def test_depth_offset_draws_cloth_over_skin_it_dips_under_by_less():
    """A garment triangle 2 mm behind the skin is hidden, and drawn with a 3 mm offset."""
    skin = MeshSequence(_triangle(0.0, half=0.8), [[0, 1, 2]], (1.0, 0.0, 0.0), "skin")
    centre = _pixel((0.0, 0.0, 0.9))
    for offset, shown in ((0.0, False), (0.003, True)):
        cloth = MeshSequence(_triangle(0.002), [[0, 1, 2]], (0.0, 0.0, 1.0), "cloth", depth_offset=offset)
        image = render_frame([skin, cloth], 0, FRONT, SIZE, ground=False)
        assert (image[centre][2] > 60) == shown and (image[centre][0] > 60) != shown


def test_offscreen_and_degenerate_triangles_are_safe():
    # Far larger than the view: every pixel is covered, nothing indexes out of bounds.
    huge = MeshSequence(_triangle(0.0, half=50.0), [[0, 1, 2]], (0.0, 1.0, 0.0), "huge")
    image = render_frame([huge], 0, FRONT, SIZE, ground=False)
    assert (image[..., 1] > 0).all() and (image[..., 0] == 0).all()
    flat = np.array([[[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.2, 0.0, 1.0]]])  # collinear
    image = render_frame([MeshSequence(flat, [[0, 1, 2]], name="line")], 0, FRONT, SIZE, ground=False)
    assert np.array_equal(image, preview._background(SIZE))


def test_mesh_behind_camera_draws_nothing():
    verts, faces = _sphere()
    behind = MeshSequence((verts + [0.0, -5.0, 1.0])[None], faces, (1.0, 0.0, 0.0), "behind")
    straddling = MeshSequence(_triangle(-3.0, half=2.0), [[0, 1, 2]], (1.0, 0.0, 0.0), "at eye")
    image = render_frame([behind, straddling], 0, FRONT, SIZE, ground=False)
    assert np.array_equal(image, preview._background(SIZE))


def test_camera_conventions():
    assert np.allclose(orbit_eye(np.zeros(3), 2.0, 0.0, 0.0), [0.0, -2.0, 0.0])  # in front of a -Y facing body
    assert orbit_eye(np.zeros(3), 2.0, 30.0, 10.0)[2] > 0
    xy, depth = project(FRONT, np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.5]]), SIZE, SIZE)
    assert np.allclose(xy[0], [SIZE / 2, SIZE / 2]) and np.isclose(depth[0], 3.0)
    assert xy[1, 1] < xy[0, 1]  # higher in the world is higher in the image (smaller row)


def test_render_preview_writes_video_and_sheet(tmp_path):
    sphere = _moving_sphere(20)
    video, sheet = render_preview([sphere], tmp_path / "out.mp4", 30.0, size=SIZE, sheet_frames=6,
                                  title="sphere", progress=False)
    assert video == tmp_path / "out.mp4" and sheet == tmp_path / "out_sheet.png"
    frames = [np.asarray(f) for f in imageio.get_reader(video)]
    assert len(frames) == 20 and frames[0].shape == (SIZE, SIZE, 3)
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 1.0
    with Image.open(sheet) as im:
        assert im.width >= 3 * SIZE and im.height >= 2 * SIZE
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mp4", "out_sheet.png"]


def test_render_preview_without_sheet_and_odd_size(tmp_path):
    video, sheet = render_preview([_moving_sphere(3)], tmp_path / "a.mp4", 24, size=65,
                                  contact_sheet=False, ground=False, progress=False)
    assert sheet is None
    assert np.asarray(imageio.get_reader(video).get_data(0)).shape == (66, 66, 3)


def _bad_inputs():
    good = _moving_sphere(4)
    nan = good.vertices.copy()
    nan[2, 5, 1] = np.nan
    short = MeshSequence(good.vertices[:3], good.faces, name="short")
    return {
        "mismatched frames": ([good, short], "x.mp4"),
        "nan vertex": ([MeshSequence(nan, good.faces)], "x.mp4"),
        "face too large": ([MeshSequence(good.vertices, good.faces + 1000)], "x.mp4"),
        "face negative": ([MeshSequence(good.vertices, good.faces - 1)], "x.mp4"),
        "wrong extension": ([good], "x.gif"),
        "no meshes": ([], "x.mp4"),
    }


@pytest.mark.parametrize("case", list(_bad_inputs()))
def test_bad_inputs_raise_parameter_error(tmp_path, case):
    meshes, name = _bad_inputs()[case]
    with pytest.raises(ParameterError) as info:
        render_preview(meshes, tmp_path / name, 30.0, size=32, progress=False)
    assert "\n" not in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_mesh_sequence_rejects_bad_shapes():
    with pytest.raises(ParameterError):
        MeshSequence(np.zeros((5, 3)), [[0, 1, 2]])
    with pytest.raises(ParameterError):
        MeshSequence(np.zeros((1, 5, 3)), [[0, 1]])
    with pytest.raises(ParameterError):
        MeshSequence(np.zeros((1, 5, 3)), [[0, 1, 2]], color=(2.0, 0.0, 0.0))


def test_failure_midway_leaves_no_files(tmp_path, monkeypatch):
    real = preview.render_frame

    def failing(meshes, frame_index, camera, size, **kwargs):
        if frame_index == 5:
            raise RuntimeError("boom")
        return real(meshes, frame_index, camera, size, **kwargs)

    monkeypatch.setattr(preview, "render_frame", failing)
    with pytest.raises(RuntimeError, match="boom"):
        render_preview([_moving_sphere(10)], tmp_path / "out.mp4", 30.0, size=SIZE, progress=False)
    assert list(tmp_path.iterdir()) == []
