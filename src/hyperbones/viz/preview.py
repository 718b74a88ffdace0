"""Render animated meshes to an H.264 MP4 plus a PNG contact sheet, headless on the CPU."""

from __future__ import annotations

import contextlib
import functools
import math
import numbers
import os
import uuid
from dataclasses import dataclass
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
from PIL import Image, ImageDraw, ImageFont
from tqdm import tqdm

from hyperbones.errors import OutputError, ParameterError

from hyperbones.io_utils import folder_problem, output_error
from hyperbones.viz.camera import Camera, follow_cameras, project
from hyperbones.viz.raster import draw_ground, rasterize, shade_mesh, splat_contact

AMBIENT = 0.28
GROUND_TILE = 0.5  # metres; big enough to read foot sliding at preview resolution
GROUND_COLORS = np.array([[206.0, 208.0, 212.0], [168.0, 172.0, 180.0]])
CONTACT_CELL = 0.025  # metres per contact-shadow cell: about a toe's width
CONTACT_REACH = 0.15  # vertices higher than this above the floor cast no contact shadow
CONTACT_STRENGTH = 0.55
CONTACT_MAX_CELLS = 256  # caps the map for scenes spread over many metres
BG_TOP, BG_BOTTOM = np.array([242.0, 244.0, 248.0]), np.array([196.0, 201.0, 210.0])


@dataclass
class MeshSequence:
    """An animated triangle mesh with fixed topology.

    vertices: (T, V, 3) world positions in metres (Z up) for T frames;
    faces: (F, 3) vertex indices; color: (3,) RGB in [0, 1];
    smooth: interpolate per-vertex normals (True) or shade each face flat.
    depth_offset: metres this mesh is moved towards the camera in the depth test only (a
    polygon offset): cloth resting on skin wins where its flat triangles, spanning vertices
    that are all outside the skin, dip under the curved skin between them.
    Arrays are converted to float32 / int32 so the compiled kernels see one type.
    """

    vertices: np.ndarray
    faces: np.ndarray
    color: np.ndarray = (0.75, 0.75, 0.75)
    name: str = "mesh"
    smooth: bool = True
    depth_offset: float = 0.0

    def __post_init__(self) -> None:
        vertices = np.asarray(self.vertices)
        faces = np.asarray(self.faces)
        color = np.asarray(self.color, dtype=np.float64)
        if vertices.ndim != 3 or vertices.shape[2] != 3 or min(vertices.shape[:2]) < 1:
            raise ParameterError(f"mesh {self.name!r}: vertices must have shape (T, V, 3), got {vertices.shape}")
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ParameterError(f"mesh {self.name!r}: faces must have shape (F, 3), got {faces.shape}")
        if faces.size and not np.issubdtype(faces.dtype, np.integer):
            raise ParameterError(f"mesh {self.name!r}: faces must be integers, got {faces.dtype}")
        if color.shape != (3,) or not np.all((color >= 0) & (color <= 1)):
            raise ParameterError(f"mesh {self.name!r}: color must be 3 floats in [0, 1], got {self.color}")
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        self.faces = np.ascontiguousarray(faces, dtype=np.int32)
        self.color = color

    @property
    def n_frames(self) -> int:
        return self.vertices.shape[0]


def _validate_meshes(meshes: list[MeshSequence]) -> int:
    """Check the scene; returns the common frame count T."""
    if not meshes:
        raise ParameterError("render_preview needs at least one mesh")
    for m in meshes:
        if not isinstance(m, MeshSequence):
            raise ParameterError(f"expected MeshSequence, got {type(m).__name__}")
        n_vertices = m.vertices.shape[1]
        if m.faces.size and (m.faces.min() < 0 or m.faces.max() >= n_vertices):
            raise ParameterError(
                f"mesh {m.name!r}: face indices must lie in [0, {n_vertices - 1}], "
                f"got [{m.faces.min()}, {m.faces.max()}]"
            )
        if not np.isfinite(m.vertices).all():
            bad = np.flatnonzero(~np.isfinite(m.vertices).all(axis=(1, 2)))
            raise ParameterError(f"mesh {m.name!r}: non-finite vertices in frame {bad[0]} ({len(bad)} frames)")
    counts = {m.name: m.n_frames for m in meshes}
    if len(set(counts.values())) > 1:
        raise ParameterError(f"meshes have different frame counts: {counts}")
    return meshes[0].n_frames


@functools.lru_cache(maxsize=4)
def _background(size: int) -> np.ndarray:
    """(size, size, 3) uint8 vertical gradient; cached because it never changes."""
    ramp = np.linspace(0.0, 1.0, size)[:, None, None]
    row = BG_TOP * (1.0 - ramp) + BG_BOTTOM * ramp
    return np.ascontiguousarray(np.broadcast_to(row, (size, size, 3)).round().astype(np.uint8))


def _light_direction(axes: np.ndarray) -> np.ndarray:
    """(3,) unit vector towards a key light above-left of the camera, so the lit
    side faces the viewer and the shading still reveals the shape."""
    right, up, forward = axes
    d = -forward + 0.6 * up - 0.4 * right
    return d / np.linalg.norm(d)


def _contact_map(meshes: list[MeshSequence], frame_index: int) -> tuple[np.ndarray, np.ndarray]:
    """Contact-shadow map of one frame: ((ny, nx) float32 darkness, (2,) world xy origin)."""
    lo = np.min([m.vertices[frame_index, :, :2].min(axis=0) for m in meshes], axis=0) - 2 * CONTACT_CELL
    hi = np.max([m.vertices[frame_index, :, :2].max(axis=0) for m in meshes], axis=0) + 2 * CONTACT_CELL
    nx, ny = np.minimum(np.ceil((hi - lo) / CONTACT_CELL).astype(int), CONTACT_MAX_CELLS)
    occlusion = np.zeros((ny, nx), np.float32)
    origin = lo.astype(np.float64)
    for m in meshes:
        splat_contact(m.vertices[frame_index], origin, CONTACT_CELL, CONTACT_REACH, occlusion)
    # A 3x3 box blur closes gaps between splatted vertices and softens the edge.
    padded = np.pad(occlusion, 1)
    blurred = sum(padded[i:i + ny, j:j + nx] for i in range(3) for j in range(3)) / 9.0
    return np.minimum(1.5 * blurred, 1.0).astype(np.float32), origin


def render_frame(
    meshes: list[MeshSequence], frame_index: int, camera: Camera, size: int, *, ground: bool = True
) -> np.ndarray:
    """Render frame `frame_index` of all meshes through `camera`. Returns (size, size, 3) uint8."""
    rgb = _background(size).copy()
    zbuf = np.full((size, size), np.inf)
    axes = camera.axes()
    focal = camera.focal(size)
    if ground:
        occlusion, origin = _contact_map(meshes, frame_index)
        fade = max(4.0, 1.5 * float(np.linalg.norm(camera.target - camera.eye)))
        draw_ground(rgb, zbuf, np.asarray(camera.eye, np.float64), axes, focal,
                    np.asarray(camera.target[:2], np.float64), GROUND_TILE, GROUND_COLORS, fade, camera.near,
                    occlusion, origin, CONTACT_CELL, CONTACT_STRENGTH)
    light = _light_direction(axes)
    for m in meshes:
        verts = m.vertices[frame_index]
        vertex_shade, face_shade = shade_mesh(verts, m.faces, light, AMBIENT)
        xy, depth = project(camera, verts, size, size)
        if m.depth_offset:
            depth = depth - m.depth_offset
        rasterize(xy, depth, vertex_shade, face_shade, m.faces, m.color, m.smooth, camera.near, rgb, zbuf)
    return rgb


def _scene_bounds(meshes: list[MeshSequence]) -> tuple[np.ndarray, np.ndarray]:
    """(T, 3) min and max over all vertices of all meshes, per frame."""
    lo = np.min([m.vertices.min(axis=1) for m in meshes], axis=0)
    hi = np.max([m.vertices.max(axis=1) for m in meshes], axis=0)
    return lo.astype(np.float64), hi.astype(np.float64)


def _font(px: int) -> ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=px)
    except (TypeError, OSError, ImportError):  # Pillow built without FreeType: fixed bitmap font
        return ImageFont.load_default()


def _title_mask(title: str, size: int) -> tuple[tuple[slice, slice], np.ndarray]:
    """Title text coverage, drawn once and blended into every frame.

    Returns the (rows, cols) slices of the text's bounding box and the (h, w, 1)
    float32 coverage in [0, 1] inside it, so per-frame blending touches only that box.
    """
    mask = Image.new("L", (size, size), 0)
    ImageDraw.Draw(mask).text((8, 6), title, fill=255, font=_font(max(12, size // 32)))
    left, top, right, bottom = mask.getbbox() or (0, 0, 1, 1)
    box = (slice(top, bottom), slice(left, right))
    return box, (np.asarray(mask, np.float32)[box] / 255.0)[..., None]


def _blend_title(frame: np.ndarray, box: tuple[slice, slice], alpha: np.ndarray) -> None:
    """Blend dark title text into frame (H, W, 3) uint8, in place."""
    region = frame[box]
    region[...] = (region * (1.0 - alpha) + 25.0 * alpha + 0.5).astype(np.uint8)


def _contact_sheet(frames: list[tuple[int, np.ndarray]], fps: float, title: str | None) -> Image.Image:
    """Grid of labelled thumbnails. frames: (frame index, (H, W, 3) uint8) pairs."""
    n = len(frames)
    cols = max(1, min(n, round(math.sqrt(n * 4 / 3))))
    rows = math.ceil(n / cols)
    thumb = min(frames[0][1].shape[0], 256)
    label_h, header_h, pad = 18, (26 if title else 0), 4
    font = _font(12)
    sheet = Image.new("RGB", (cols * (thumb + pad) + pad, header_h + rows * (thumb + label_h + pad) + pad), "white")
    draw = ImageDraw.Draw(sheet)
    if title:
        draw.text((pad + 2, 6), title, fill=(20, 20, 20), font=_font(16))
    for k, (index, image) in enumerate(frames):
        x = pad + (k % cols) * (thumb + pad)
        y = header_h + pad + (k // cols) * (thumb + label_h + pad)
        sheet.paste(Image.fromarray(image).resize((thumb, thumb), Image.Resampling.BILINEAR), (x, y))
        draw.text((x + 2, y + thumb + 2), f"frame {index}  t={index / fps:.2f} s", fill=(30, 30, 30), font=font)
    return sheet


def _temp_beside(path: Path, suffix: str) -> Path:
    """A fresh hidden name in path's directory (same filesystem, so os.replace is atomic).

    Only the name is reserved: the writer creates the file, so it gets the
    usual umask permissions rather than mkstemp's 0600.
    """
    return path.with_name(f".{path.stem}.{uuid.uuid4().hex[:12]}{suffix}")


def _complete_mp4(path: Path) -> bool:
    """Whether ``path`` is a whole MP4: its top-level boxes (ISO 14496-12 §4.2: 32-bit size,
    type; size 1: a 64-bit size follows; size 0: to the end) tile the file exactly and
    include the movie header ``moov`` and the media data ``mdat``."""
    end = path.stat().st_size
    seen = set()
    with open(path, "rb") as f:
        at = 0
        while at < end:
            f.seek(at)
            head = f.read(16)
            if len(head) < 8:
                return False
            size, kind = int.from_bytes(head[:4], "big"), head[4:8]
            if size == 1:
                if len(head) < 16:
                    return False
                size = int.from_bytes(head[8:16], "big")
            elif size == 0:
                size = end - at
            if size < 8:
                return False
            seen.add(kind)
            at += size
    return at == end and {b"moov", b"mdat"} <= seen


def render_preview(
    meshes: list[MeshSequence],
    out_path: str | Path,
    fps: float,
    *,
    size: int = 512,
    contact_sheet: bool = True,
    sheet_frames: int = 12,
    ground: bool = True,
    title: str | None = None,
    progress: bool = True,
) -> tuple[Path, Path | None]:
    """Render all frames to an H.264 MP4 (and `<stem>_sheet.png` when contact_sheet).

    meshes share one follow camera per frame; size is the square frame edge in
    pixels (rounded up to even, as yuv420p needs); title, when given, is drawn in
    the top-left of every frame and above the sheet. Outputs are written to temp
    files beside the targets and renamed into place only when complete, so a
    failure leaves neither partial nor temp files; one to write them (read-only
    folder, full disk) is an ``OutputError``. Returns (mp4 path, sheet path or None).
    """
    out_path = Path(out_path)
    if out_path.suffix.lower() != ".mp4":
        raise ParameterError(f"preview output must end in .mp4, got {out_path.name!r}")
    if not (isinstance(fps, numbers.Real) and math.isfinite(fps) and fps > 0):
        raise ParameterError(f"fps must be a positive number, got {fps!r}")
    if int(size) < 16:
        raise ParameterError(f"size must be at least 16 pixels, got {size}")
    if int(sheet_frames) < 1:
        raise ParameterError(f"sheet_frames must be at least 1, got {sheet_frames}")
    size = int(size) + int(size) % 2
    n_frames = _validate_meshes(meshes)
    sheet_path = out_path.with_name(f"{out_path.stem}_sheet.png") if contact_sheet else None

    cameras = follow_cameras(*_scene_bounds(meshes), fps)
    sheet_indices = set(np.linspace(0, n_frames - 1, min(sheet_frames, n_frames)).round().astype(int).tolist())
    title_alpha = _title_mask(title, size) if title else None

    made = [folder for folder in (out_path.parent, *out_path.parent.parents) if not folder.exists()]
    temps: list[Path] = []
    writer = None
    writing = out_path  # the output a failure is about
    try:
        out_path.parent.mkdir(parents=True, exist_ok=True)
        tmp_video = _temp_beside(out_path, ".tmp.mp4")  # ffmpeg picks the container from the suffix
        temps.append(tmp_video)
        # Made here, so a folder that refuses it says why; ffmpeg (silenced: its own lines
        # would break the one-line error) writes over it.
        tmp_video.open("xb").close()
        writer = imageio.get_writer(
            tmp_video, format="FFMPEG", mode="I", fps=fps, codec="libx264", quality=5,
            pixelformat="yuv420p", macro_block_size=2, ffmpeg_log_level="quiet",
            output_params=["-preset", "veryfast", "-movflags", "+faststart"],
        )
        kept: list[tuple[int, np.ndarray]] = []
        for t in tqdm(range(n_frames), desc="preview", unit="frame", disable=not progress):
            frame = render_frame(meshes, t, cameras[t], size, ground=ground)
            if title_alpha is not None:
                _blend_title(frame, *title_alpha)
            writer.append_data(frame)
            if t in sheet_indices:
                kept.append((t, frame))
        writer.close()
        writer = None
        if not _complete_mp4(tmp_video):  # the writer does not check how ffmpeg ended
            why = folder_problem(out_path.parent) or "ffmpeg stopped before the video was complete"
            raise OutputError(out_path, f"cannot write: {why}")
        if sheet_path is not None:
            writing = sheet_path
            tmp_sheet = _temp_beside(sheet_path, ".tmp.png")
            temps.append(tmp_sheet)
            _contact_sheet(kept, fps, title).save(tmp_sheet, format="PNG")
        # Both files are complete before either is renamed into place.
        writing = out_path
        os.replace(tmp_video, out_path)
        if sheet_path is not None:
            writing = sheet_path
            os.replace(tmp_sheet, sheet_path)
        made = []
    except Exception as error:
        failure = output_error(writing, error)
        if failure is None or failure is error:
            raise
        raise failure from error
    finally:
        if writer is not None:
            try:
                writer.close()
            except Exception:  # already failing; the original error matters more
                pass
        for tmp in temps:
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
        for folder in made:  # made for this preview, deepest first
            with contextlib.suppress(OSError):
                folder.rmdir()
    return out_path, sheet_path
