"""UV rasterisation and sampling back at the vertices."""

import pytest
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.uv_raster import UvRaster


def _strip(gap: float):
    """A 2×1 strip of 4 triangles in 3D, cut along x = 1 into two UV charts ``gap`` apart.

    The middle column of vertices (x = 1) has two UV copies, one per chart.
    """
    vertices = torch.tensor([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], dtype=torch.float32)
    faces = torch.tensor([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    scale, left, right = 0.3, 0.1, 0.1 + 0.3 + gap
    uvs = torch.tensor([[left, 0.2], [left + scale, 0.2], [left, 0.2 + scale], [left + scale, 0.2 + scale],
                        [right, 0.2], [right + scale, 0.2], [right, 0.2 + scale], [right + scale, 0.2 + scale]])
    face_uvs = torch.tensor([[0, 1, 3], [0, 3, 2], [4, 5, 7], [4, 7, 6]])
    return vertices, faces, uvs, face_uvs


def test_linear_fields_come_back_exactly():
    """x, y are linear over each chart, so rasterise -> sample returns them, border vertices
    included (the padding continues each chart linearly)."""
    vertices, faces, uvs, face_uvs = _strip(0.2)
    raster = UvRaster.build(faces, uvs, face_uvs, len(vertices), resolution=64)
    image = raster.rasterize(vertices[None])
    assert image.shape == (1, 3, 64, 64)
    assert torch.allclose(raster.sample(image)[0], vertices, atol=1e-4)


def test_touching_charts_are_not_mixed():
    """Charts 0.06 texel apart: a tap on the other chart is dropped, so the seam vertex is off
    by at most about a texel's worth of the field (x changes 0.052 m per texel here), not by
    the other chart's values."""
    vertices, faces, uvs, face_uvs = _strip(0.001)
    raster = UvRaster.build(faces, uvs, face_uvs, len(vertices), resolution=64)
    error = (raster.sample(raster.rasterize(vertices[None]))[0] - vertices).norm(dim=1)
    assert float(error[[0, 2, 3, 5]].max()) < 1e-4
    assert float(error.max()) < 0.052


def test_a_seam_vertex_gets_one_value_from_both_charts():
    vertices, faces, uvs, face_uvs = _strip(0.2)
    raster = UvRaster.build(faces, uvs, face_uvs, len(vertices), resolution=64)
    image = torch.zeros(1, 1, 64, 64)
    image[..., :, :32] = 1.0  # the left chart reads 1, the right one 0
    values = raster.sample(image)[0, :, 0]
    assert values[[0, 3]].tolist() == [1.0, 1.0]
    assert values[[2, 5]].tolist() == [0.0, 0.0]
    assert values[[1, 4]].tolist() == [0.5, 0.5]  # the seam: mean of its two copies


def test_coverage_and_batching():
    vertices, faces, uvs, face_uvs = _strip(0.2)
    raster = UvRaster.build(faces, uvs, face_uvs, len(vertices), resolution=100)
    # Two 0.3 × 0.3 charts cover 18 % of the image.
    assert float(raster.coverage.mean()) == pytest.approx(0.18, abs=0.01)
    batch = torch.randn(5, len(vertices), 7)
    images = raster.rasterize(batch)
    assert images.shape == (5, 7, 100, 100)
    assert raster.sample(images).shape == (5, len(vertices), 7)
    assert torch.allclose(raster.rasterize(batch[2:3]), images[2:3])


def test_template_round_trip(body):
    from hyperbones.garment.templates import make_template

    garment = make_template("dress", body, vertices=1500)
    raster = UvRaster.build(garment.faces, garment.uvs, garment.face_uvs, garment.num_vertices, resolution=128)
    error = (raster.sample(raster.rasterize(garment.vertices[None]))[0] - garment.vertices).norm(dim=1)
    assert float(error.max()) < 0.01  # metres; charts smaller than a texel are the worst case


def test_bad_resolution():
    vertices, faces, uvs, face_uvs = _strip(0.2)
    with pytest.raises(ParameterError, match="at least 4"):
        UvRaster.build(faces, uvs, face_uvs, len(vertices), resolution=2)
