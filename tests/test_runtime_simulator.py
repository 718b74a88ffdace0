"""The per-frame runtime on real identities (Anny body, templates) and a built-in motion."""

import copy

import pytest
import torch

from hyperbones.body.skeleton import skinning_transforms
from hyperbones.errors import ParameterError
from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.geometry.rotations import rot_z
from hyperbones.models.hyperbones import HyperBonesModel
from hyperbones.models.module_a import heading_frame
from hyperbones.runtime.identity import encode_identity
from hyperbones.runtime.config import RuntimeConfig
from hyperbones.runtime.simulator import Simulator, transform_points

from test_runtime_identity import SMALL


@pytest.fixture(scope="module")
def setup(body):
    from hyperbones.garment.templates import make_template
    from hyperbones.motion.builtin import builtin_motion

    torch.manual_seed(0)
    model = HyperBonesModel(SMALL)
    with torch.no_grad():
        identities = [encode_identity(model, make_template(name, body, vertices=1500), body)
                      for name in ("tshirt", "long-skirt")]
    motion = builtin_motion("walk", body, duration=1.0)
    return model, identities, motion


def _trained_looking(model):
    """A copy whose zero-started output layers have weights, as training would give them."""
    model = copy.deepcopy(model)
    torch.manual_seed(1)
    for layer in (model.runtime.bone_net.corrections, model.runtime.refiner.out, model.runtime.modulator.net[-1]):
        torch.nn.init.normal_(layer.weight, std=0.02)
    return model


def _run(simulator, rotations, roots):
    return torch.stack([torch.stack(simulator.step(rotations[:, t], roots[:, t]))
                        for t in range(rotations.shape[1])], dim=1)  # (N,T,V,3) for equal V


def test_untrained_runtime_is_virtual_bone_skinning(setup, body):
    model, identities, motion = setup
    identity = identities[0]
    out = _run(Simulator(model.runtime, [identity], config=RuntimeConfig(follow=1.0, loose_follow=1.0)), motion.joint_rotations[None],
               motion.root_translation[None])[0]
    posed = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=False)
    rotations, positions = identity.bones.pose(posed.skinning_transforms)
    expected = linear_blend_skinning(identity.rest_vertices, identity.weights,
                                     skinning_transforms(identity.bones.rest_positions, rotations, positions))
    assert torch.allclose(out, expected, atol=1e-4)


def test_same_motion_elsewhere_gives_the_same_cloth_motion(setup):
    """The network works in the character's heading frame: a motion turned about Z and moved
    gives the turned and moved garment."""
    model, identities, motion = setup
    model = _trained_looking(model)
    turn, shift = rot_z(torch.tensor(2.0)), torch.tensor([3.0, -1.0, 0.0])
    rotations = motion.joint_rotations[None]
    roots = motion.root_translation[None]
    here = _run(Simulator(model.runtime, identities[:1]), rotations, roots)[0]
    there = _run(Simulator(model.runtime, identities[:1]), turn @ rotations, roots @ turn.T + shift)[0]
    assert torch.allclose(there, here @ turn.T + shift, atol=2e-4)
    first = _run(Simulator(model.runtime, identities[:1]), rotations[:, :1], roots[:, :1])[0, 0]
    assert (here[-1] - first).abs().max() > 0.01  # and the garment did move


def test_batched_characters_match_single_ones(setup):
    """Two garments, the first twice (its rows skinned and rasterised as one group), each on its own motion."""
    model, identities, motion = setup
    model = _trained_looking(model)
    characters = [identities[0], identities[1], identities[0]]
    rotations = torch.stack([motion.joint_rotations, motion.joint_rotations.flip(0), motion.joint_rotations.roll(7, 0)])
    roots = torch.stack([motion.root_translation, motion.root_translation.flip(0), motion.root_translation.roll(7, 0)])
    together = Simulator(model.runtime, characters)
    alone = [Simulator(model.runtime, [identity]) for identity in characters]
    for t in range(5):
        all_three = together.step(rotations[:, t], roots[:, t])
        for i in range(3):
            assert torch.allclose(all_three[i], alone[i].step(rotations[i:i + 1, t], roots[i:i + 1, t])[0], atol=1e-5)
    assert not torch.allclose(all_three[0], all_three[2], atol=1e-3)  # the copies moved apart


def test_without_the_conv_mlp_the_runtime_is_its_bones_alone(setup):
    """``conv_mlp=false``: the output of a model whose Conv-MLP adds nothing (its last layer
    zeroed), and no UV stage is timed; on, the trained-looking Conv-MLP moves the garment."""
    from hyperbones.runtime.stage_clock import StageClock

    model, identities, motion = setup
    model = _trained_looking(model)
    silent = copy.deepcopy(model)
    torch.nn.init.zeros_(silent.runtime.refiner.out.weight)
    torch.nn.init.zeros_(silent.runtime.refiner.out.bias)
    rotations, roots = motion.joint_rotations[None, :8], motion.root_translation[None, :8]
    without = Simulator(model.runtime, identities[:1], config=RuntimeConfig(conv_mlp=False))
    clock = StageClock()
    without.profile(clock)
    bones = _run(without, rotations, roots)
    assert torch.allclose(bones, _run(Simulator(silent.runtime, identities[:1]), rotations, roots), atol=1e-6)
    assert not torch.allclose(bones, _run(Simulator(model.runtime, identities[:1]), rotations, roots), atol=1e-4)
    assert "Conv-MLP" not in clock.per_frame() and "Bone-Net" in clock.per_frame()


def test_reset_forgets_the_motion(setup):
    model, identities, motion = setup
    simulator = Simulator(_trained_looking(model).runtime, identities[:1])
    rotations, roots = motion.joint_rotations[None], motion.root_translation[None]
    first = simulator.step(rotations[:, 10], roots[:, 10])[0]
    simulator.step(rotations[:, 11], roots[:, 11])
    simulator.reset()
    assert torch.equal(simulator.step(rotations[:, 10], roots[:, 10])[0], first)


def test_follow_moves_part_way_to_module_a_in_the_heading_frame_and_settles_on_it(setup):
    model, identities, motion = setup
    runtime = _trained_looking(model).runtime
    rotations, roots = motion.joint_rotations[None, :12], motion.root_translation[None, :12]
    direct = Simulator(runtime, identities[:1], config=RuntimeConfig(follow=1.0, loose_follow=1.0))
    targets = _run(direct, rotations, roots)[0]  # (T,V,3)
    follow = Simulator(runtime, identities[:1], config=RuntimeConfig(follow=0.5, carry_lag=0.0))
    outputs = _run(follow, rotations, roots)[0]
    assert torch.equal(outputs[0], targets[0])  # the first frame has nothing to follow from
    local = transform_points(heading_frame(rotations[0, :, 0], roots[0]), torch.stack([outputs, targets]))
    # Each frame goes half the way from the last output to Module A's, both in that frame's heading frame.
    assert torch.allclose(local[0, 1:], local[0, :-1] + 0.5 * (local[1, 1:] - local[0, :-1]), atol=1e-5)
    assert float((outputs[-1] - targets[-1]).norm(dim=-1).max()) > 1e-3  # it lags a walking body
    for _ in range(30):  # the body holds its last pose
        held, settled = follow.step(rotations[:, -1], roots[:, -1])[0], direct.step(rotations[:, -1], roots[:, -1])[0]
    assert float((held - settled).norm(dim=-1).max()) < 1e-5  # and settles where Module A is
    with pytest.raises(ParameterError, match="follow"):
        RuntimeConfig(follow=0.0)
    with pytest.raises(ParameterError, match="loose_follow"):
        RuntimeConfig(loose_follow=1.5)
    with pytest.raises(ParameterError, match="carry_lag"):
        RuntimeConfig(carry_lag=1.0)


def test_carry_lag_carries_by_a_blend_of_this_and_the_last_frame_to_frame_motion(setup):
    model, identities, motion = setup
    runtime = _trained_looking(model).runtime
    rotations, roots = motion.joint_rotations[None, :12], motion.root_translation[None, :12]
    targets = _run(Simulator(runtime, identities[:1], config=RuntimeConfig(follow=1.0, loose_follow=1.0)), rotations, roots)[0]
    outputs = _run(Simulator(runtime, identities[:1], config=RuntimeConfig(follow=0.5, carry_lag=0.25)), rotations, roots)[0]
    heading = heading_frame(rotations[0, :, 0], roots[0])  # (T,4,4) world -> heading frame
    moves = torch.linalg.inv(heading[1:]) @ heading[:-1]  # (T-1,4,4): frame t-1 -> t
    expected = [targets[0], targets[1] + 0.5 * (transform_points(moves[0], targets[0]) - targets[1])]
    for t in range(2, len(targets)):
        carried = transform_points(moves[t - 1] + 0.25 * (moves[t - 2] - moves[t - 1]), expected[-1])
        expected.append(carried + 0.5 * (targets[t] - carried))
    assert torch.allclose(outputs, torch.stack(expected), atol=1e-5)
    assert float((outputs - _run(Simulator(runtime, identities[:1], config=RuntimeConfig(follow=0.5, carry_lag=0.0)), rotations,
                                 roots)[0]).norm(dim=-1).max()) > 1e-4  # the lag made a difference


def test_loose_cloth_lags_by_its_own_share_after_the_body_stops(setup, body):
    """The long skirt's hem is loose cloth: with a smaller ``loose_follow`` it is still further
    from where it settles a few frames after the stop, and it does settle there."""
    model, identities, motion = setup
    runtime = _trained_looking(model).runtime
    frames = 12
    posed = body.pose(motion.joint_rotations[:frames], motion.root_translation[:frames])
    rotations, roots = motion.joint_rotations[None, :frames], motion.root_translation[None, :frames]
    skirt = identities[1]
    hem = torch.argsort(skirt.rest_vertices[:, 2])[: len(skirt.rest_vertices) // 20]

    def hem_after_stop(loose_follow):
        simulator = Simulator(runtime, [skirt], body_faces=body.faces,
                              config=RuntimeConfig(follow=0.6, loose_follow=loose_follow))
        for t in range(frames):
            simulator.step(rotations[:, t], roots[:, t], posed.vertices[None, t])
        held = [simulator.step(rotations[:, -1], roots[:, -1], posed.vertices[None, -1])[0][hem] for _ in range(40)]
        return [float((positions - held[-1]).norm(dim=-1).mean()) for positions in held]

    even, loose = hem_after_stop(0.6), hem_after_stop(0.2)
    assert loose[2] > 1.5 * even[2] and loose[2] > 1e-3
    assert loose[-2] < 0.02 * loose[2]  # and settles


def test_bad_input(setup):
    model, identities, _ = setup
    with pytest.raises(ParameterError, match="at least one identity"):
        Simulator(model.runtime, [])
    simulator = Simulator(model.runtime, identities)
    with pytest.raises(ParameterError, match=r"step expects \(2,31,3,3\)"):
        simulator.step(torch.eye(3).expand(1, 31, 3, 3), torch.zeros(1, 3))
