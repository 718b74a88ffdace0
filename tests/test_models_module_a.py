"""Module A's networks: the local frame, Bone-Net with FiLM, bone corrections, the Conv-MLP."""

import math
from dataclasses import asdict, replace

import pytest
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.rotations import rot_z
from hyperbones.models.module_a import (ModuleA, ModuleAConfig, bone_window_features, correct_bones,
                                        heading_frame)

SMALL = ModuleAConfig(num_bones=8, shape_code=16, hidden=32, pose_embedding=4, uv_features=5, uv_resolution=16,
                      bone_net="global")
PER_BONE = replace(SMALL, bone_net="per-bone", window_frames=4)


def test_heading_frame_puts_the_hips_at_the_origin_facing_minus_y():
    yaw = torch.tensor(0.8)
    tilt = torch.tensor([[1.0, 0, 0], [0, math.cos(0.2), -math.sin(0.2)], [0, math.sin(0.2), math.cos(0.2)]])
    hips = rot_z(yaw) @ tilt  # a heading plus a forward lean, which the frame ignores
    root = torch.tensor([1.0, 2.0, 0.9])
    frame = heading_frame(hips, root)
    assert torch.allclose(frame[:3, :3] @ root + frame[:3, 3], torch.zeros(3), atol=1e-6)
    facing = rot_z(yaw) @ torch.tensor([0.0, -1.0, 0.0])
    assert torch.allclose(frame[:3, :3] @ facing, torch.tensor([0.0, -1.0, 0.0]), atol=1e-6)
    assert torch.allclose(frame[2, :3], torch.tensor([0.0, 0.0, 1.0]))  # Z stays up


def test_window_features():
    window = torch.zeros(2, 3, 8, 3)
    window[:, 2, :, 0] = 0.01  # one centimetre along x in the last frame
    features = bone_window_features(window)
    assert features.shape == (2, ModuleAConfig(num_bones=8).window_features) == (2, 9 * 8)
    assert torch.allclose(features[:, : 3 * 8].reshape(2, 8, 3)[..., 0], torch.full((2, 8), 0.01))  # positions at t
    displacement = features[:, 3 * 8:].reshape(2, 8, 2, 3)
    assert torch.allclose(displacement[:, :, 1, 0], torch.ones(2, 8))  # centimetres per frame
    assert torch.allclose(displacement[:, :, 0], torch.zeros(2, 8, 3))


def test_a_longer_window_sees_motion_that_a_short_one_has_forgotten():
    """A bone moved 5 frames ago, then stood still: K = 3 sees only stillness, K = 8 the move."""
    window = torch.zeros(1, 8, 4, 3)
    window[:, 3:, :, 2] = 0.02  # the move is between frames 2 and 3 of eight
    still = torch.zeros_like(window[:, -3:])
    still[:] = window[:, -1:]
    assert torch.equal(bone_window_features(window[:, -3:]), bone_window_features(still))
    long = bone_window_features(window)
    assert long.shape == (1, ModuleAConfig(num_bones=4, window_frames=8).window_features)
    assert long[:, 3 * 4:].abs().sum() > 0


def test_window_of_one_frame_is_refused():
    with pytest.raises(ParameterError, match="window_frames"):
        ModuleAConfig(window_frames=1)


def test_untrained_module_a_changes_nothing():
    torch.manual_seed(0)
    model = ModuleA(SMALL)
    film = model.modulator(torch.randn(3, SMALL.shape_code))
    assert torch.allclose(film[:, :, 0], torch.ones(3, SMALL.layers, SMALL.hidden))
    assert torch.allclose(film[:, :, 1], torch.zeros(3, SMALL.layers, SMALL.hidden))
    delta, embedding = model.bone_net(torch.randn(3, SMALL.window_features), film)
    assert delta.shape == (3, SMALL.num_bones, 9) and embedding.shape == (3, SMALL.pose_embedding)
    assert torch.equal(delta, torch.zeros_like(delta))
    images = model.refine(torch.randn(3, 3, 16, 16), torch.ones(3, 1, 16, 16), torch.randn(3, 5, 16, 16), embedding)
    assert images.shape == (3, 3, 16, 16) and torch.equal(images, torch.zeros_like(images))


def test_film_changes_the_output():
    torch.manual_seed(1)
    model = ModuleA(SMALL)
    for layer in (model.bone_net.corrections, model.modulator.net[-1]):
        torch.nn.init.normal_(layer.weight, std=0.1)
    features = torch.randn(1, SMALL.window_features)
    a = model.bone_net(features, model.modulator(torch.randn(1, SMALL.shape_code)))[0]
    b = model.bone_net(features, model.modulator(torch.randn(1, SMALL.shape_code)))[0]
    assert (a - b).abs().max() > 1e-3


def test_untrained_per_bone_net_changes_nothing():
    torch.manual_seed(2)
    model = ModuleA(PER_BONE)
    window = torch.randn(3, 4, 8, 3) * 0.1
    codes = torch.randn(3, 8, PER_BONE.bone_code_features)
    delta, embedding = model.bone_corrections(window, codes, model.modulator(torch.randn(3, PER_BONE.shape_code)))
    assert delta.shape == (3, 8, 9) and embedding.shape == (3, PER_BONE.pose_embedding)
    assert torch.equal(delta, torch.zeros_like(delta))


def test_per_bone_net_follows_the_bones_not_their_order():
    """Listing the same bones in another order reorders their corrections and leaves φ as it is."""
    torch.manual_seed(3)
    model = ModuleA(PER_BONE)
    torch.nn.init.normal_(model.bone_net.corrections.weight, std=0.1)
    window = torch.randn(2, 4, 8, 3) * 0.1
    codes = torch.randn(2, 8, PER_BONE.bone_code_features)
    film = model.modulator(torch.randn(2, PER_BONE.shape_code))
    order = torch.randperm(8)
    delta, embedding = model.bone_corrections(window, codes, film)
    moved, moved_embedding = model.bone_corrections(window[:, :, order], codes[:, order], film)
    assert delta.abs().max() > 1e-3
    assert torch.allclose(moved, delta[:, order], atol=1e-6)
    assert torch.allclose(moved_embedding, embedding, atol=1e-6)
    other = codes.clone()
    other[:, 0] += 1.0  # another bone code: that bone's correction changes
    assert (model.bone_corrections(window, other, film)[0][:, 0] - delta[:, 0]).abs().max() > 1e-4


def test_bone_net_choice_and_old_configs():
    with pytest.raises(ParameterError, match="bone_net"):
        ModuleAConfig(bone_net="mlp")
    saved = asdict(PER_BONE)
    del saved["bone_net"]  # a checkpoint from before the choice existed
    assert ModuleAConfig.from_dict(saved).bone_net == "global"
    assert ModuleAConfig.from_dict(asdict(PER_BONE)).bone_net == "per-bone"


def test_bone_corrections():
    rotations = rot_z(torch.tensor([0.3, -1.2]))[:, None].expand(2, 4, 3, 3)
    positions = torch.randn(2, 4, 3)
    same_r, same_p = correct_bones(rotations, positions, torch.zeros(2, 4, 9))
    assert torch.allclose(same_r, rotations, atol=1e-6) and torch.equal(same_p, positions)
    delta = torch.randn(2, 4, 9)
    new_r, new_p = correct_bones(rotations, positions, delta)
    assert torch.allclose(new_r @ new_r.transpose(-1, -2), torch.eye(3).expand(2, 4, 3, 3), atol=1e-5)
    assert torch.allclose(torch.linalg.det(new_r), torch.ones(2, 4), atol=1e-5)
    assert torch.allclose(new_p, positions + delta[..., 6:])


def test_no_conv_ablation():
    model = ModuleA(ModuleAConfig(**{**SMALL.__dict__, "use_conv": False}))
    assert model.refiner is None
    out = model.refine(torch.randn(1, 3, 16, 16), torch.ones(1, 1, 16, 16), torch.randn(1, 5, 16, 16),
                       torch.randn(1, 4))
    assert torch.equal(out, torch.zeros_like(out))


@pytest.mark.parametrize("resolution", [16, 24])
def test_conv_runs_at_any_resolution_and_learns(resolution):
    torch.manual_seed(2)
    model = ModuleA(SMALL)
    x = torch.randn(1, 3, resolution, resolution)
    out = model.refine(x, torch.ones(1, 1, resolution, resolution), torch.randn(1, 5, resolution, resolution),
                       torch.randn(1, 4))
    out.sum().backward()
    assert model.refiner.out.weight.grad.abs().sum() > 0  # the zero-started layer gets a gradient


def test_inference_copy_keeps_the_model_and_its_answer():
    """``for_inference``: the shipped Conv-MLP channels-last gives the float32 answer; in bfloat16
    it stays within a millimetre; the trained module itself is left as it was."""
    from hyperbones.models.loading import hyperbones_payload, model_of

    module_a = model_of(hyperbones_payload(None, "cpu"), "cpu").runtime
    config = module_a.config
    torch.manual_seed(4)
    resolution = 24
    inputs = (torch.randn(1, 3, resolution, resolution) * 0.3, torch.ones(1, 1, resolution, resolution),
              torch.randn(1, config.uv_features, resolution, resolution), torch.randn(1, config.pose_embedding))
    with torch.no_grad():
        reference = module_a.refine(*inputs)
        fast = module_a.for_inference("cpu").refine(*inputs)
        half = module_a.for_inference("cpu", bfloat16=True).refine(*inputs)
        again = module_a.refine(*inputs)
    assert module_a.refiner.inp.weight.dtype == torch.float32 and module_a.refiner.inp.weight.is_contiguous()
    assert torch.equal(again, reference)
    assert reference.abs().max() > 1e-3  # the trained Conv-MLP displaces by millimetres or more
    assert fast.dtype == half.dtype == torch.float32
    assert (fast - reference).abs().max() < 1e-6
    difference = (half - reference).abs()
    assert 0 < difference.max() < 2e-3 and difference.pow(2).mean().sqrt() < 5e-4
