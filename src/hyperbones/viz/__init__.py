"""Headless CPU preview of animated meshes: numba rasteriser, follow camera, MP4 + contact sheet."""

from hyperbones.viz.preview import MeshSequence, render_frame, render_preview

__all__ = ["MeshSequence", "render_frame", "render_preview"]
