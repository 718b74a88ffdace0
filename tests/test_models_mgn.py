"""The MeshGraphNet trunk: shapes, sum aggregation, and that edge order does not matter."""

import torch

from hyperbones.models.mgn import EdgeSet, MeshGraphNet


def _graph(num_nodes=7, num_edges=20, seed=0):
    g = torch.Generator().manual_seed(seed)
    senders = torch.randint(0, num_nodes, (num_edges,), generator=g)
    receivers = torch.randint(0, num_nodes, (num_edges,), generator=g)
    return (torch.randn(num_nodes, 5, generator=g),
            {"mesh": EdgeSet(senders, receivers, torch.randn(num_edges, 4, generator=g)),
             "world": EdgeSet(receivers[:6], senders[:6], torch.randn(6, 4, generator=g))})


def test_trunk_shapes_and_gradients():
    torch.manual_seed(0)
    trunk = MeshGraphNet(5, {"mesh": 4, "world": 4}, latent=16, num_blocks=3)
    nodes, edges = _graph()
    out = trunk(nodes, edges)
    assert out.shape == (7, 16)
    out.square().sum().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in trunk.parameters())


def test_edge_order_does_not_change_the_result():
    torch.manual_seed(0)
    trunk = MeshGraphNet(5, {"mesh": 4, "world": 4}, latent=16, num_blocks=3)
    nodes, edges = _graph()
    order = torch.randperm(20)
    mesh = edges["mesh"]
    shuffled = dict(edges, mesh=EdgeSet(mesh.senders[order], mesh.receivers[order], mesh.features[order]))
    assert torch.allclose(trunk(nodes, edges), trunk(nodes, shuffled), atol=1e-5)


def test_messages_reach_only_along_edges():
    """With one block, a node with no incoming edges ignores every other node."""
    torch.manual_seed(0)
    trunk = MeshGraphNet(5, {"mesh": 4, "world": 4}, latent=16, num_blocks=1)
    nodes = torch.randn(3, 5)
    empty = EdgeSet(torch.zeros(0, dtype=torch.long), torch.zeros(0, dtype=torch.long), torch.zeros(0, 4))
    edges = {"mesh": EdgeSet(torch.tensor([0]), torch.tensor([1]), torch.randn(1, 4)), "world": empty}
    base = trunk(nodes, edges)
    changed = nodes.clone()
    changed[0] += 1.0
    after = trunk(changed, edges)
    assert not torch.allclose(base[1], after[1])  # node 1 hears node 0
    assert torch.allclose(base[2], after[2])  # node 2 hears nobody


def test_normalizer_statistics_skip_blown_up_batches():
    from hyperbones.models.normalizer import Normalizer

    normalizer = Normalizer(2)
    normalizer(torch.tensor([[1.0, 2.0], [3.0, 6.0]]))
    mean, std = normalizer.mean.clone(), normalizer.std.clone()
    out = normalizer(torch.tensor([[float("nan"), 1.0], [1e200, 0.0]], dtype=torch.float64))
    assert torch.equal(normalizer.mean, mean) and torch.equal(normalizer.std, std)
    assert torch.isfinite(out[1, 1])  # the finite entries are still normalised with the kept statistics
    normalizer(torch.tensor([[5.0, 10.0]]))
    assert torch.allclose(normalizer.mean, torch.tensor([3.0, 6.0], dtype=torch.float64))
