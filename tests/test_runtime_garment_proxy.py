"""A garment's proxy (a decimated copy the runtime corrects in its place) and the runtime with one."""

import pytest
import torch

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.geometry.proximity import BodyProximity
from hyperbones.runtime.config import RuntimeConfig
from hyperbones.runtime.garment_proxy import GarmentProxy
from hyperbones.runtime.identity import Identity, encode_identity
from hyperbones.runtime.simulator import Simulator

from test_runtime_identity import SMALL


@pytest.fixture(scope="module")
def tshirt(body):
    from hyperbones.garment.templates import make_template

    return make_template("tshirt", body, vertices=1500)


@pytest.fixture(scope="module")
def proxy(tshirt):
    return GarmentProxy.build(tshirt.vertices, tshirt.faces, 500)


def _edge_lengths(vertices, faces):
    edges = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return (vertices[edges[:, 0]] - vertices[edges[:, 1]]).norm(dim=1)


def test_a_proxy_is_some_of_the_garments_vertices_and_holds_every_one(tshirt, proxy):
    assert 400 <= proxy.num_vertices <= 650
    assert len(torch.unique(proxy.vertex)) == proxy.num_vertices
    assert int(proxy.faces.min()) >= 0 and int(proxy.faces.max()) < proxy.num_vertices
    assert bool((proxy.weights >= 0).all()) and torch.allclose(proxy.weights.sum(1), torch.ones(tshirt.num_vertices))
    rest = tshirt.vertices.float()
    # Every vertex lies on the proxy's surface at rest, to well within a proxy edge.
    held = proxy.spread(rest[proxy.vertex])
    proxy_edge = _edge_lengths(rest[proxy.vertex], proxy.faces).mean()
    assert float((held - rest).norm(dim=1).max()) < 0.25 * float(proxy_edge)
    # The proxy's own vertices take exactly their own values, and a rigid motion spreads rigidly.
    values = torch.randn(proxy.num_vertices, 3)
    assert torch.equal(proxy.spread(values)[proxy.vertex], values)
    shift = torch.tensor([0.1, -0.2, 0.3])
    assert torch.allclose(proxy.spread(rest[proxy.vertex] + shift), held + shift, atol=1e-6)


def test_bad_proxy_sizes_are_refused(tshirt):
    with pytest.raises(ParameterError, match="at least 100"):
        GarmentProxy.build(tshirt.vertices, tshirt.faces, 50)
    with pytest.raises(ParameterError, match="proxy_vertices=50 must be 0"):
        RuntimeConfig(proxy_vertices=50)


def test_an_identity_keeps_its_proxy_through_save_and_load(body, tshirt, tmp_path):
    from hyperbones.models.hyperbones import HyperBonesModel

    torch.manual_seed(0)
    with torch.no_grad():
        identity = encode_identity(HyperBonesModel(SMALL), tshirt, body)
    assert identity.with_proxy(0) is identity and identity.with_proxy(tshirt.num_vertices) is identity
    with_proxy = identity.with_proxy(500)
    assert with_proxy.proxy is not None and with_proxy.with_proxy(500) is with_proxy
    assert with_proxy.with_proxy(0).proxy is None
    loaded = Identity.load(with_proxy.save(tmp_path / "identity.pt"))
    for name in ("vertex", "faces", "corners", "weights"):
        assert torch.equal(getattr(loaded.proxy, name), getattr(with_proxy.proxy, name)), name
    assert loaded.proxy.target == 500
    assert Identity.load(identity.save(tmp_path / "plain.pt")).proxy is None
    payload = torch.load(tmp_path / "identity.pt", weights_only=True)
    payload["proxy"]["corners"][0, 0] = 10**6
    torch.save(payload, tmp_path / "bad.pt")
    with pytest.raises(InputFileError, match=r"bad\.pt: damaged identity cache: proxy corners has indices outside"):
        Identity.load(tmp_path / "bad.pt")


def test_the_runtime_on_a_proxy_keeps_the_garment_out_of_the_body_and_its_edges_at_length(body):
    """The shipped model on a 1,500-vertex t-shirt walking, corrected on a 500-vertex proxy: the
    garment ends outside the body and less stretched than Module A left it, like the runtime
    that corrects every vertex, at far fewer searched points."""
    from hyperbones.garment.draped import draped_garment
    from hyperbones.motion.load import load_motion

    garment, rest = draped_garment("tshirt", body, vertices=1500)
    motion = load_motion("walk", body).slice(0, 20)
    posed = body.pose(motion.joint_rotations, motion.root_translation)
    roots = posed.joint_positions[:, 0]
    proximity = BodyProximity(body.faces)
    results = {}
    for name, overrides in (("raw", {"contact": False, "follow": 1.0, "loose_follow": 1.0}),
                            ("proxy", {"proxy_vertices": 500}), ("full", {"proxy_vertices": 0})):
        simulator = Simulator.load([(garment, body)], overrides=overrides, rest_vertices=[rest])
        assert (simulator.proxies[0] is not None) == (name == "proxy")
        inside, strain = [], []
        for t in range(posed.joint_rotations.shape[0]):
            bodies = posed.vertices[t:t + 1] if simulator.contact is not None else None
            out = simulator.step(posed.joint_rotations[t:t + 1], roots[t:t + 1], bodies)[0]
            proximity.update(posed.vertices[t])
            inside.append(float((proximity.query(out, max_distance=0.05).signed_distance < 0).float().mean()))
            strain.append(float((_edge_lengths(out, garment.faces) / _edge_lengths(rest.float(), garment.faces)
                                 - 1).abs().mean()))
        results[name] = (max(inside[5:]), sum(strain[5:]) / len(strain[5:]))
    assert results["proxy"][0] <= 0.002 < results["raw"][0]
    assert results["proxy"][1] < 0.8 * results["raw"][1]
    assert results["proxy"][1] < 1.2 * results["full"][1]


def test_the_identity_command_saves_the_models_proxy(body, tmp_path, capsys):
    """``hyperbones identity`` bakes the shipped runtime's proxy into the cache, so a machine
    without pymeshlab (a game engine's host, the GPU machines) can step it."""
    from hyperbones.cli import main

    out = tmp_path / "tshirt.identity.pt"
    assert main(["identity", "--garment", "tshirt", "--vertices", "1500", "--out", str(out)]) == 0
    assert "proxy" in capsys.readouterr().out
    proxy = Identity.load(out).proxy
    assert proxy is not None and proxy.target == 1000 and proxy.num_vertices < 1500
