import random

import torch

from hyperbones.physics.energies import GRAVITY
from hyperbones.training.config import DataConfig
from hyperbones.training.data import TeacherData, ballistic_hops


def test_ballistic_hops_fly_at_minus_g():
    heights = ballistic_hops(120, 30.0, random.Random(3), speeds=(1.5, 2.0))
    assert heights.shape == (120,) and float(heights.min()) >= 0.0
    assert 0.1 < float(heights.max()) < 2.0 ** 2 / (2 * GRAVITY) + 0.01  # apex of the fastest launch at most
    curvature = (heights[2:] - 2 * heights[1:-1] + heights[:-2]) * 30.0 ** 2  # m/s²
    # Frames whose 11-frame neighbourhood is all off the ground: clear of the smoothed take-off and landing.
    flying = -torch.nn.functional.max_pool1d(-heights[None, None], 11, stride=1, padding=5)[0, 0][1:-1] > 0
    assert flying.sum() > 10
    assert torch.allclose(curvature[flying], torch.tensor(-GRAVITY), atol=0.02)  # float32 heights
    grounded = (heights == 0).sum()
    assert grounded > 0  # pauses between hops


def test_episodes_get_hops_on_their_root(body):
    config = DataConfig(templates=("tshirt",), resolutions=(1000,), train_clips=(), builtins=("idle",),
                        hold_seconds=0.0, airborne_fraction=1.0, hop_speeds=(1.5, 1.5))
    data = TeacherData(config, seed=0)
    episode = data.sample_episode(40)
    lowest = episode.body_vertices[..., 2].amin(-1)  # (T,) the idle body's feet, lifted by the hops
    assert float(lowest.max() - lowest.min()) > 0.08
    still = TeacherData(DataConfig(**{**config.__dict__, "airborne_fraction": 0.0}), seed=0).sample_episode(40)
    assert float(still.body_vertices[..., 2].amin(-1).max() - still.body_vertices[..., 2].amin(-1).min()) < 0.03
