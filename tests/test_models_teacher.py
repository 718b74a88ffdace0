"""The teacher's integrator."""

import torch

from hyperbones.models.teacher import integrate


def test_integrate_is_symplectic_euler_with_pinned_vertices_following():
    positions = torch.zeros(3, 3)
    velocities = torch.tensor([[0.01, 0.0, 0.0]] * 3)
    acceleration = torch.tensor([[0.0, 0.0, -0.002]] * 3)
    pinned = torch.tensor([False, False, True])
    pinned_next = torch.full((3, 3), 0.5)
    x, v = integrate(positions, velocities, acceleration, pinned, pinned_next)
    assert torch.allclose(v[:2], torch.tensor([0.01, 0.0, -0.002]).expand(2, 3))
    assert torch.allclose(x[:2], v[:2])  # x(t+1) = x(t) + v(t+1)
    assert torch.equal(x[2], pinned_next[2]) and torch.equal(v[2], pinned_next[2])


def test_the_autocast_teacher_answers_in_float32_close_to_the_float32_one():
    """``Autocast`` (train.bfloat16) runs the network's products in bfloat16 and hands back float32."""
    from hyperbones.models.cloth_graph import ClothGraph
    from hyperbones.models.mgn import EdgeSet
    from hyperbones.models.teacher import Autocast, Teacher, TrunkConfig

    torch.manual_seed(0)
    teacher = Teacher(TrunkConfig(latent=32, blocks=3)).eval()
    with torch.no_grad():
        teacher.decoder[-1].weight.mul_(100.0)  # away from the near-zero start, so the outputs are not all rounding
    nodes, edges = 400, 2400
    graph = ClothGraph(torch.randn(nodes, 21), {
        name: EdgeSet(torch.randint(0, nodes, (edges,)), torch.randint(0, nodes, (edges,)), torch.randn(edges, 8))
        for name in ("mesh", "world")}, num_garment=300)
    with torch.no_grad():
        exact, rounded = teacher(graph), Autocast(teacher)(graph)
    assert rounded.dtype == torch.float32 and rounded.shape == exact.shape == (300, 3)
    error = (rounded - exact).norm() / exact.norm()
    assert 0 < float(error) < 0.05  # bfloat16 rounding: a few per mille to a few per cent, never exact


def test_the_compiled_teacher_answers_as_the_eager_one_at_every_size():
    """``hyperbones rollouts --compile``: one compilation (shapes dynamic) answers graphs of two
    sizes as the eager network does, to float32 rounding."""
    from hyperbones.models.cloth_graph import ClothGraph
    from hyperbones.models.mgn import EdgeSet
    from hyperbones.models.teacher import Teacher, TrunkConfig
    from hyperbones.training.rollouts import compiled_for_inference

    torch.manual_seed(0)
    teacher = Teacher(TrunkConfig(latent=16, blocks=2)).eval()
    with torch.no_grad():
        teacher.decoder[-1].weight.mul_(100.0)  # away from the near-zero start
    compiled = compiled_for_inference(teacher)
    for nodes, edges, garment in ((400, 2400, 300), (650, 3100, 500)):
        graph = ClothGraph(torch.randn(nodes, 21), {
            name: EdgeSet(torch.randint(0, nodes, (edges,)), torch.randint(0, nodes, (edges,)), torch.randn(edges, 8))
            for name in ("mesh", "world")}, num_garment=garment)
        with torch.no_grad():
            exact, fast = teacher(graph), compiled(graph)
        assert fast.shape == exact.shape == (garment, 3)
        torch.testing.assert_close(fast, exact, atol=1e-5, rtol=1e-4)


def test_compiling_without_a_compiler_is_a_clear_error(monkeypatch, tmp_path):
    import pytest

    from hyperbones.errors import ParameterError
    from hyperbones.models.teacher import Teacher, TrunkConfig
    from hyperbones.training.rollouts import compiled_for_inference

    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("CXX", raising=False)
    with pytest.raises(ParameterError, match="needs a C\\+\\+ compiler"):
        compiled_for_inference(Teacher(TrunkConfig(latent=16, blocks=1)))
