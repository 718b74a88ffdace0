"""Preview of a body moving through a motion (and, later, what it wears)."""

from __future__ import annotations

from pathlib import Path

from hyperbones.body.anny_body import Body
from hyperbones.motion.motion import Motion
from hyperbones.viz.preview import MeshSequence, render_preview

BODY_COLOR = (0.86, 0.72, 0.62)


def body_mesh_sequence(body: Body, motion: Motion) -> MeshSequence:
    """The posed body over every frame of ``motion`` as a renderable mesh sequence."""
    posed = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=True)
    return MeshSequence(posed.vertices.numpy(), body.faces.numpy(), BODY_COLOR, name="body")


def render_motion(
    body: Body,
    motion: Motion,
    out_path: str | Path,
    extra_meshes: list[MeshSequence] | None = None,
    size: int = 512,
    progress: bool = True,
) -> tuple[Path, Path | None]:
    """Render the body (and any extra meshes) to an MP4 plus a contact sheet beside it."""
    meshes = [body_mesh_sequence(body, motion), *(extra_meshes or [])]
    title = f"{motion.name} | body {body.shape.label()} | {motion.num_frames} frames @ {motion.fps:g} fps"
    return render_preview(meshes, out_path, motion.fps, size=size, title=title, progress=progress)
