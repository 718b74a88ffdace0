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


def test_draped_identities_settle_the_carried_garment(body, tmp_path, monkeypatch):
    """data.drape: the garment a rollout starts from (and bones bind to) is the carried one
    settled on the body, cached on disk; the physics rest shape stays the carried one."""
    from dataclasses import replace

    monkeypatch.setenv("HYPERBONES_CACHE_DIR", str(tmp_path))  # its own cache: it counts the files

    from hyperbones.body.shape import BodyShape
    from hyperbones.physics.material import Material
    from hyperbones.garment.draped import cache_dir

    config = DataConfig(templates=("tshirt-open",), resolutions=(1000,), train_clips=(), builtins=("idle",), drape=True)
    shape = BodyShape(gender=0.8, age=0.4, muscle=0.3, weight=0.8, height=0.3, proportions=0.6)
    draped = TeacherData(config, seed=0).identity_for("tshirt-open", 1000, shape, Material())
    carried = TeacherData(replace(config, drape=False), seed=0).identity_for("tshirt-open", 1000, shape, Material())
    assert draped.draped and not carried.draped
    assert torch.equal(draped.rest.rest_vertices, carried.rest.rest_vertices)
    moved = (draped.garment.vertices - carried.garment.vertices).norm(dim=-1)
    assert float(moved.max()) > 0.005  # the open panels and hem fell under gravity
    assert float(draped.garment.vertices[:, 2].mean()) < float(carried.garment.vertices[:, 2].mean())
    files = list((cache_dir() / "training-drapes").glob("tshirt-open-1000-*.pt"))
    assert len(files) == 1
    again = TeacherData(config, seed=1).identity_for("tshirt-open", 1000, shape, Material())
    assert torch.equal(again.garment.vertices, draped.garment.vertices)  # from the cache
    other = TeacherData(config, seed=1).identity_for("tshirt-open", 1000, shape, Material(density=0.3))
    assert len(list((cache_dir() / "training-drapes").glob("tshirt-open-1000-*.pt"))) == 2  # the fabric is in the key
    assert not torch.equal(other.garment.vertices, draped.garment.vertices)
