"""The body–garment graph: world edges, body nodes and features of a real garment on Anny."""

import pytest
import torch

from hyperbones.garment.templates import make_template
from hyperbones.geometry.proximity import BodyProximity
from hyperbones.models.cloth_graph import EDGE_FEATURES, NODE_FEATURES, WORLD_RADIUS, GarmentTopology, build_graph
from hyperbones.physics.cloth import ClothRest


@pytest.fixture(scope="module")
def tshirt(body):
    return make_template("tshirt", body, 1000)


def test_graph_of_a_garment_on_the_body(body, tshirt):
    rest = ClothRest.from_mesh(tshirt.vertices, tshirt.faces)
    topology = GarmentTopology.build(tshirt.vertices, tshirt.faces, tshirt.pinned, rest.vertex_masses, rest.material)
    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    nearest = proximity.query(tshirt.vertices, max_distance=0.1)
    velocity = torch.full_like(tshirt.vertices, 0.01)
    moved_body = body.rest_vertices + torch.tensor([0.0, 0.0, 0.02])
    graph = build_graph(topology, tshirt.vertices, velocity, tshirt.vertices, body.rest_vertices, moved_body,
                        body.faces, nearest)
    V = tshirt.num_vertices
    close = int((nearest.found & (nearest.signed_distance.abs() < WORLD_RADIUS)).sum())
    world = graph.edge_sets["world"]
    assert world.senders.shape == (3 * close,) and world.features.shape == (3 * close, EDGE_FEATURES)
    assert bool((world.senders >= V).all()) and bool((world.receivers < V).all())
    num_nodes = graph.node_features.shape[0]
    assert graph.node_features.shape[1] == NODE_FEATURES and num_nodes == V + len(torch.unique(world.senders))
    assert graph.edge_sets["mesh"].senders.shape[0] == 2 * len(tshirt.edges())
    assert torch.isfinite(graph.node_features).all()
    # Garment velocities (cm per frame) and the body's 2 cm step are where the docstring says.
    assert torch.allclose(graph.node_features[:V, 0:3], torch.full((V, 3), 1.0))
    assert torch.allclose(graph.node_features[V:, 9:12], torch.tensor([0.0, 0.0, 2.0]).expand(num_nodes - V, 3), atol=1e-4)
    # Body nodes carry the body type, garment nodes free/pinned.
    assert bool((graph.node_features[V:, 8] == 1).all()) and bool((graph.node_features[:V, 8] == 0).all())
    # At rest, mesh edges' current and rest parts agree.
    mesh = graph.edge_sets["mesh"].features
    assert torch.allclose(mesh[:, :4], mesh[:, 4:], atol=1e-4)
