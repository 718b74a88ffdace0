"""Fuzzing ``runtime.identity.Identity.load`` with a small identity cache made by the real pipeline
(a template on the Anny body, Module B of a small model) and then damaged: bytes truncated or
changed, and the saved payload re-saved with entries missing, reshaped, of other types, NaN or
out of range, or of another version. Each case loads an identity whose tensors fit together (and
which rasterises and samples finite values) or raises the package's one-line error naming the file."""

from __future__ import annotations

import copy
import io
import re

import pytest
import torch
from hypothesis import strategies as st
from test_fuzz_support import fuzz, loads_or_fails_cleanly, mutations, write_case

from hyperbones.errors import InputFileError
from hyperbones.models.hyperbones import HyperBonesConfig, HyperBonesModel
from hyperbones.models.module_a import ModuleAConfig
from hyperbones.models.teacher import TrunkConfig
from hyperbones.runtime.identity import Identity, encode_identity

SMALL = HyperBonesConfig(TrunkConfig(latent=8, blocks=1),
                         ModuleAConfig(num_bones=8, shape_code=8, hidden=16, layers=2, pose_embedding=4, uv_features=4,
                                       uv_resolution=16, conv_channels=(4, 8, 4)))


@pytest.fixture(scope="module")
def saved(body, tmp_path_factory) -> bytes:
    """The bytes of a small identity cache as ``Identity.save`` writes them."""
    from hyperbones.garment.templates import make_template

    torch.manual_seed(0)
    with torch.no_grad():
        identity = encode_identity(HyperBonesModel(SMALL), make_template("tshirt", body, vertices=1000), body)
    return identity.save(tmp_path_factory.mktemp("identity") / "tshirt.identity.pt").read_bytes()


ODD = (None, "x", 3, 2.5, [1, 2], {"a": 1}, torch.zeros(0), torch.zeros(2, 2), torch.tensor(float("nan")))


def _change_tensor(draw, value: torch.Tensor) -> object:
    change = draw(st.sampled_from(["nan", "inf", "negative index", "huge index", "drop row", "transpose", "flat",
                                   "int", "float", "odd"]))
    if change in ("nan", "inf"):
        return value.double().fill_(float(change)) if value.numel() else value
    if change == "negative index":
        return value - value.abs().max() - 1 if value.numel() else value
    if change == "huge index":
        return value + 10**6
    if change == "drop row":
        return value[:-1]
    if change == "transpose":
        return value.T if value.ndim == 2 else value[None]
    if change == "flat":
        return value.reshape(-1)
    if change == "int":
        return value.to(torch.int64)
    if change == "float":
        return value.to(torch.float32)
    return draw(st.sampled_from(ODD))


@st.composite
def changed_payload(draw, original: bytes) -> bytes:
    payload = torch.load(io.BytesIO(original), weights_only=True)
    payload = copy.deepcopy(payload)
    for _ in range(draw(st.integers(1, 2))):
        table = payload
        key = draw(st.sampled_from(sorted(payload)))
        if isinstance(payload[key], dict) and payload[key] and draw(st.booleans()):
            table, key = payload[key], draw(st.sampled_from(sorted(payload[key])))
        value = table[key]
        change = draw(st.sampled_from(["drop", "extra", "value", "value", "value"]))
        if change == "drop":
            table.pop(key)
        elif change == "extra":
            table[f"{key}_v3"] = value
        elif isinstance(value, torch.Tensor):
            table[key] = _change_tensor(draw, value)
        elif isinstance(value, list):  # a sparse matrix's shape
            table[key] = draw(st.sampled_from([[value[1], value[0]], [value[0]], [-1, value[1]], value + [1], "x",
                                               torch.tensor(value), [float(v) for v in value]]))
        else:  # version, name, resolution
            table[key] = draw(st.sampled_from([*ODD, 1, 3, 0, -16, 10**6, True]))
    out = io.BytesIO()
    torch.save(payload, out)
    return out.getvalue()


def _sound(identity: Identity) -> None:
    """What the per-frame runtime relies on."""
    v, b = identity.num_vertices, identity.weights.shape[1]
    r, d_f = identity.raster.resolution, identity.vertex_features.shape[1]
    assert identity.rest_vertices.shape == (v, 3) and identity.rest_joint_positions.shape == (31, 3)
    assert identity.faces.ndim == 2 and identity.faces.shape[1] == 3 and identity.face_uvs.shape == identity.faces.shape
    assert 0 <= int(identity.faces.min()) and int(identity.faces.max()) < v
    assert 0 <= int(identity.face_uvs.min()) and int(identity.face_uvs.max()) < len(identity.uvs)
    assert identity.bones.rest_positions.shape == (b, 3) and identity.bones.log_weights.shape == (v, b)
    assert identity.bones.joint_weights.shape == (b, 31) and identity.bones.garment_vertex.shape == (b,)
    assert identity.features_uv.shape == (d_f, r, r) and identity.film.ndim == 3 and identity.film.shape[1] == 2
    for tensor in (identity.rest_vertices, identity.rest_joint_positions, identity.weights, identity.film,
                   identity.features_uv, identity.vertex_features, identity.uvs, identity.bones.rest_positions,
                   identity.bones.joint_weights):
        assert torch.isfinite(tensor).all()
    assert not torch.isnan(identity.bones.log_weights).any()
    images = identity.raster.rasterize(identity.vertex_features[None])
    assert images.shape == (1, d_f, r, r) and torch.isfinite(identity.raster.sample(images)).all()


def test_saved_identity_loads(saved, tmp_path):
    _sound(Identity.load(write_case(tmp_path / "identity.pt", saved)))


def test_fuzz_damaged_identity(saved, tmp_path):
    def case(data: bytes):
        path = write_case(tmp_path / "identity.pt", data)
        identity = loads_or_fails_cleanly(lambda: Identity.load(path), path)
        if identity is not None:
            _sound(identity)

    fuzz(st.one_of(mutations(saved, text=False), changed_payload(saved), changed_payload(saved)), case)


def test_other_files_are_not_identities(tmp_path):
    for data in (b"", b"not a torch file", b"PK\x03\x04"):
        path = write_case(tmp_path / "other.pt", data)
        with pytest.raises(InputFileError, match="not a hyperbones identity cache"):
            Identity.load(path)


def _resaved(original: bytes, change) -> bytes:
    payload = torch.load(io.BytesIO(original), weights_only=True)
    change(payload)
    out = io.BytesIO()
    torch.save(payload, out)
    return out.getvalue()


@pytest.mark.parametrize("change, phrase", [
    (lambda p: p.update(version=torch.zeros(0)), "not a version-2 hyperbones identity cache"),  # ambiguous truth value
    (lambda p: p["raster"].pop("raster_shape"), "its raster entry is not a table"),  # KeyError
    (lambda p: p["bones"].update(extra=torch.zeros(1)), "its bones entry is not a table"),  # TypeError
    (lambda p: p.update(weights=p["weights"][:-1]), "weights has shape"),  # loaded, failed per frame
    (lambda p: p.update(film=p["film"].fill_(float("nan"))), "film holds NaN"),  # loaded silently
    (lambda p: p.update(faces=p["faces"] + 10**6), "faces has indices outside"),  # loaded silently
    (lambda p: p["raster"].update(raster_shape=torch.tensor(p["raster"]["raster_shape"])), "raster_shape is"),
])
def test_identity_damage_the_fuzzing_found(saved, tmp_path, change, phrase):
    path = write_case(tmp_path / "found.pt", _resaved(saved, change))
    with pytest.raises(InputFileError, match=re.escape(phrase)) as error:
        Identity.load(path)
    assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)
