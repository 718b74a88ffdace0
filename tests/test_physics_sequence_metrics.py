"""Sequence metrics' soundness check: a rollout that blew up or fell off is named, not scored silently."""

import pytest
import torch

from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.sequence_metrics import RUNAWAY_SPEED, runaway_problem, sequence_metrics
from hyperbones.jobs.simulate import run_simulation


@pytest.fixture(scope="module")
def skinned_skirt(body):
    """Ten frames of the long skirt skinned on the built-in walk (1,500 vertices)."""
    return run_simulation("lbs", "long-skirt", "walk", None, frames=10, vertices=1500)


def test_a_falling_or_nan_garment_is_reported_and_a_sound_one_is_not(skinned_skirt):
    result = skinned_skirt
    assert runaway_problem(result.metrics) is None
    x = result.garment_vertices.double()
    rest = ClothRest.from_mesh(result.garment.vertices.double(), result.garment.faces)

    def metrics(trajectory):
        return sequence_metrics(trajectory, rest, result.body_vertices, result.body_faces,
                                origin=result.joint_positions[0, 0], dt=1.0 / result.fps)

    # The same skirt in free fall from 2 s after it let go: it passes RUNAWAY_SPEED.
    seconds = 2.0 + torch.arange(x.shape[0], dtype=x.dtype) / result.fps
    falling = x.clone()
    falling[..., 2] -= (0.5 * 9.81 * seconds.square())[:, None]
    assert 9.81 * float(seconds[-1]) > RUNAWAY_SPEED and "m/s" in runaway_problem(metrics(falling))
    broken = x.clone()
    broken[5, 0] = float("nan")
    assert "NaN" in runaway_problem(metrics(broken))


def test_run_simulation_warns_when_the_garment_runs_away(monkeypatch, body):
    monkeypatch.setattr("hyperbones.physics.sequence_metrics.RUNAWAY_SPEED", 1e-3)
    with pytest.warns(UserWarning, match="lbs on long-skirt, walk: a garment vertex reached"):
        run_simulation("lbs", "long-skirt", "walk", None, frames=10, vertices=1500)


def test_detached_pct_counts_the_vertex_frames_that_left_the_skin(skinned_skirt, body):
    result = skinned_skirt
    assert result.metrics["detached_pct"] < 1.0  # skinning keeps the skirt where the drape put it
    assert 500 < result.metrics["hem_area_cm2"] < 5000  # the hem loop seen from above, about the hips' girth
    x = result.garment_vertices.double()
    rest = ClothRest.from_mesh(result.garment.vertices.double(), result.garment.faces)
    off = x.clone()
    off[7:, :, 2] += 3.0  # the last three frames' skirt far above the head, beyond any search
    off[4, :, 0] += 0.05  # one frame shifted by less than the margin: still on
    metrics = sequence_metrics(off, rest, result.body_vertices, result.body_faces,
                               origin=result.joint_positions[0, 0], dt=1.0 / result.fps,
                               drape=(result.garment.vertices, body.rest_vertices))
    assert metrics["detached_pct"] == pytest.approx(30.0, abs=1.0)
