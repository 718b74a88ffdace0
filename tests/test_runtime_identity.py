"""The identity cache: Module B's outputs folded into tensors, saved and loaded."""

import pytest
import torch

from hyperbones.errors import InputFileError
from hyperbones.models.hyperbones import HyperBonesConfig, HyperBonesModel
from hyperbones.models.module_a import ModuleAConfig
from hyperbones.models.teacher import TrunkConfig
from hyperbones.runtime.identity import Identity, encode_identity

SMALL = HyperBonesConfig(TrunkConfig(latent=16, blocks=2),
                         ModuleAConfig(num_bones=32, shape_code=16, hidden=32, uv_features=4, uv_resolution=32))


@pytest.fixture(scope="module")
def tshirt(body):
    from hyperbones.garment.templates import make_template

    return make_template("tshirt", body, vertices=1500)


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    model = HyperBonesModel(SMALL)
    for head in (model.encoder.weight_head[-1], model.encoder.feature_head):  # as if trained
        torch.nn.init.normal_(head.weight, std=0.5)
    return model


@pytest.fixture(scope="module")
def identity(body, tshirt, model):
    with torch.no_grad():
        return encode_identity(model, tshirt, body)


def _texels_in_uv_triangles(uvs: torch.Tensor, face_uvs: torch.Tensor, resolution: int):
    """An independent rasterisation: for each texel centre ((col+½)/R, (row+½)/R), the first UV
    triangle holding it (−1: none) and its barycentric coordinates there, (R²,), (R²,3)."""
    centres = (torch.arange(resolution, dtype=torch.float64) + 0.5) / resolution
    rows, cols = torch.meshgrid(centres, centres, indexing="ij")
    points = torch.stack([cols.reshape(-1), rows.reshape(-1)], 1)[:, None]  # (R²,1,2)
    a, b, c = (uvs.double()[face_uvs[:, k]][None] for k in range(3))  # (1,F,2)

    def cross(o, p, q):
        return (p[..., 0] - o[..., 0]) * (q[..., 1] - o[..., 1]) - (p[..., 1] - o[..., 1]) * (q[..., 0] - o[..., 0])

    area = cross(a, b, c)  # (1,F) twice the signed area
    beta, gamma = cross(a, points, c) / area, cross(a, b, points) / area  # weights of b and c
    bary = torch.stack([1 - beta - gamma, beta, gamma], -1)  # (R²,F,3)
    inside = (bary.amin(-1) >= 0) & (area.abs() > 1e-12)
    face = torch.where(inside.any(1), inside.float().argmax(1), -1)
    return face, bary[torch.arange(len(face)), face.clamp_min(0)]


def test_contents(identity):
    v = identity.num_vertices
    assert identity.weights.shape == (v, 32)
    assert torch.allclose(identity.weights.sum(1), torch.ones(v), atol=1e-5)
    # Δw moved the weights away from the geodesic ones.
    assert (identity.weights - identity.bones.log_weights.exp()).abs().max() > 1e-3
    assert identity.film.shape == (SMALL.runtime.layers, 2, SMALL.runtime.hidden)
    assert identity.features_uv.shape == (4, 32, 32) and identity.features_uv.abs().sum() > 0
    assert identity.rest_joint_positions.shape == (31, 3)


def test_save_load_round_trip(identity, tmp_path):
    loaded = Identity.load(identity.save(tmp_path / "tshirt.identity.pt"))
    assert loaded.name == identity.name
    for name in ("rest_vertices", "faces", "weights", "film", "features_uv", "rest_joint_positions",
                 "vertex_features", "uvs", "face_uvs"):
        assert torch.equal(getattr(loaded, name), getattr(identity, name))
    for name, value in identity.bones.state_dict().items():
        assert torch.equal(getattr(loaded.bones, name), value), name
    assert loaded.raster.resolution == identity.raster.resolution
    assert torch.equal(loaded.raster.coverage, identity.raster.coverage)
    for matrix in ("raster", "sampler"):
        assert torch.equal(getattr(loaded.raster, matrix).to_dense(), getattr(identity.raster, matrix).to_dense())


def test_uv_maps_hold_the_garment(identity, tshirt):
    """The UV maps at two resolutions: coverage marks exactly the texels inside a UV
    triangle, F_UV is f_v interpolated there, and a smooth field comes back from the image."""
    errors = {}
    for resolution in (16, 32):
        at = identity.at_resolution(resolution)
        assert at.raster.resolution == resolution and at.features_uv.shape == (4, resolution, resolution)
        face, bary = _texels_in_uv_triangles(tshirt.uvs, tshirt.face_uvs, resolution)
        coverage = at.raster.coverage.reshape(-1)
        assert set(coverage.unique().tolist()) <= {0.0, 1.0}
        assert torch.equal(coverage.bool(), face >= 0)
        covered = torch.nonzero(face >= 0).squeeze(1)
        expected = (bary[covered, :, None] * identity.vertex_features.double()[tshirt.faces[face[covered]]]).sum(1)
        assert torch.allclose(at.features_uv.reshape(4, -1)[:, covered].T.double(), expected, atol=1e-5)
        # The garment's rest positions (a smooth field) through the image and back.
        points = identity.rest_vertices
        errors[resolution] = (at.raster.sample(at.raster.rasterize(points[None]))[0] - points).norm(dim=1)
    assert float(errors[32].mean()) < 0.003 and float(errors[32].max()) < 0.03  # metres
    assert float(errors[16].mean()) > 2 * float(errors[32].mean())  # a coarser image holds the field less well
    # All the charts: the covered share of the image is the UV triangles' total area, to a texel's border.
    a, b, c = (tshirt.uvs.double()[tshirt.face_uvs[:, k]] for k in range(3))
    uv_area = 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]).abs().sum()
    assert float(identity.raster.coverage.mean()) == pytest.approx(float(uv_area), abs=0.02)


def test_other_resolution(body, tshirt, model, identity):
    with torch.no_grad():
        other = encode_identity(model, tshirt, body, uv_resolution=16)
    assert other.features_uv.shape == (4, 16, 16) and other.raster.resolution == 16
    # The resolution changes the UV maps only: the same weights and FiLM parameters.
    assert torch.equal(other.weights, identity.weights) and torch.equal(other.film, identity.film)
    # A cache rebuilds its UV maps at another resolution from f_v and the atlas: the same
    # maps as encoding at that resolution.
    rebuilt = identity.at_resolution(16)
    assert torch.equal(rebuilt.raster.coverage, other.raster.coverage)
    assert torch.allclose(rebuilt.features_uv, other.features_uv, atol=1e-6)
    assert torch.equal(rebuilt.raster.sampler.to_dense(), other.raster.sampler.to_dense())
    again = identity.at_resolution(32)
    assert again is identity


def test_bad_files(tmp_path):
    with pytest.raises(InputFileError, match="identity cache not found"):
        Identity.load(tmp_path / "missing.pt")
    junk = tmp_path / "junk.pt"
    junk.write_text("not torch")
    with pytest.raises(InputFileError, match="junk.pt: not a hyperbones identity cache"):
        Identity.load(junk)
    other = tmp_path / "other.pt"
    torch.save({"version": 99}, other)
    with pytest.raises(InputFileError, match="not a version-2"):
        Identity.load(other)
