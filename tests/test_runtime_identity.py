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
def identity(body):
    from hyperbones.garment.templates import make_template

    torch.manual_seed(0)
    model = HyperBonesModel(SMALL)
    for head in (model.encoder.weight_head[-1], model.encoder.feature_head):  # as if trained
        torch.nn.init.normal_(head.weight, std=0.5)
    with torch.no_grad():
        return encode_identity(model, make_template("tshirt", body, vertices=1500), body)


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
    assert torch.equal(loaded.bones.log_weights, identity.bones.log_weights)
    x = torch.randn(1, identity.num_vertices, 3)
    assert torch.allclose(loaded.raster.sample(loaded.raster.rasterize(x)),
                          identity.raster.sample(identity.raster.rasterize(x)))


def test_other_resolution(body, identity):
    from hyperbones.garment.templates import make_template

    model = HyperBonesModel(SMALL)
    with torch.no_grad():
        other = encode_identity(model, make_template("tshirt", body, vertices=1500), body, uv_resolution=16)
    assert other.features_uv.shape == (4, 16, 16) and other.raster.resolution == 16
    # A cache rebuilds its UV maps at another resolution from f_v and the atlas.
    rebuilt = identity.at_resolution(16)
    assert rebuilt.raster.resolution == 16 and rebuilt.features_uv.shape == (4, 16, 16)
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
