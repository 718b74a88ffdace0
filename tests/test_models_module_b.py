"""Module B: heads on the teacher's trunk over the canonical graph of a real garment on Anny."""

import torch

from hyperbones.geometry.proximity import BodyProximity
from hyperbones.models.cloth_graph import GarmentTopology, canonical_graph
from hyperbones.models.hyperbones import HyperBonesConfig, HyperBonesModel
from hyperbones.models.module_a import ModuleAConfig
from hyperbones.models.teacher import TrunkConfig
from hyperbones.physics.cloth import ClothRest


def _graph(body):
    from hyperbones.garment.templates import make_template

    garment = make_template("tshirt", body, vertices=1500)
    rest = ClothRest.from_mesh(garment.vertices, garment.faces, garment.material)
    topology = GarmentTopology.build(rest.rest_vertices, garment.faces, garment.pinned, rest.vertex_masses,
                                     garment.material)
    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    graph = canonical_graph(topology, body.rest_vertices, body.faces, proximity.query(garment.vertices))
    return garment, graph


def test_canonical_graph_is_the_still_garment(body):
    garment, graph = _graph(body)
    assert graph.num_garment == garment.num_vertices
    garment_nodes = graph.node_features[: garment.num_vertices]
    assert torch.equal(garment_nodes[:, :3], torch.zeros(garment.num_vertices, 3))  # no velocity
    assert len(graph.edge_sets["world"].senders) > 0  # the tight tshirt touches the body


def test_heads_share_the_teacher_trunk(body):
    torch.manual_seed(0)
    model = HyperBonesModel(HyperBonesConfig(TrunkConfig(latent=16, blocks=2),
                                             ModuleAConfig(num_bones=32, shape_code=24, uv_features=6)))
    # One trunk, held by the teacher: the state dict has no second copy.
    assert not any(name.startswith("encoder.") and "trunk" in name for name in model.state_dict())
    garment, graph = _graph(body)
    code = model.encode(graph)
    assert code.shape_code.shape == (24,)
    assert code.weight_corrections.shape == (garment.num_vertices, 32)
    assert code.vertex_features.shape == (garment.num_vertices, 6)
    # The Δw and f_v heads start at zero: the geodesic weights and an empty F_UV.
    assert torch.equal(code.weight_corrections, torch.zeros_like(code.weight_corrections))
    # A loss on the shape code trains the shared trunk (what the teacher runs on).
    code.shape_code.square().sum().backward()
    assert model.teacher.trunk.node_encoder[0].weight.grad.abs().sum() > 0


def test_canonical_graphs_leave_the_trunk_statistics_and_can_leave_its_weights_alone(body):
    torch.manual_seed(0)
    model = HyperBonesModel(HyperBonesConfig(TrunkConfig(latent=16, blocks=2),
                                             ModuleAConfig(num_bones=32, shape_code=24, uv_features=6))).train()
    _, graph = _graph(body)
    statistics = {name: value.clone() for name, value in model.teacher.state_dict().items() if "normal" in name}
    assert statistics  # the trunk's input normalisers
    code = model.encode(graph, train_trunk=False)
    for name, value in model.teacher.state_dict().items():
        if name in statistics:
            assert torch.equal(value, statistics[name]), name
    assert all(child.training for child in model.modules())  # the mode is given back
    code.shape_code.square().sum().backward()
    assert model.teacher.trunk.node_encoder[0].weight.grad is None  # the trunk learns nothing from B's loss
    assert model.encoder.shape_head[0].weight.grad.abs().sum() > 0  # B's heads do
