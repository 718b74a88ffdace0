"""The reference physics method: each frame's incremental potential minimised by L-BFGS."""

import torch

from hyperbones.geometry.proximity import BodyProximity
from hyperbones.jobs.simulate import run_simulation


def test_physics_rollout_hangs_still_and_stays_outside_the_body(body):
    result = run_simulation("physics", "tshirt", "idle", None, frames=3, vertices=1000, device="cpu")
    x = result.garment_vertices
    assert x.shape == (3, result.garment.num_vertices, 3) and torch.isfinite(x).all()
    assert result.metrics["method"] == "physics"
    # The settled shirt hangs: no free vertex rises more than 1 cm from frame 1 on.
    pinned = torch.zeros(x.shape[1], dtype=torch.bool)
    pinned[result.garment.pinned] = True
    drop = (x[1, ~pinned, 2] - x[-1, ~pinned, 2])
    assert float(drop.min()) > -0.01
    proximity = BodyProximity(result.body_faces)
    proximity.update(result.body_vertices[-1].float())
    inside = proximity.query(x[-1].float(), max_distance=0.1).signed_distance < 0
    assert float(inside.float().mean()) < 0.01


def test_each_frame_lowers_the_step_energy_below_the_explicit_guess(body):
    from hyperbones.garment.draped import draped_garment
    from hyperbones.training.physics_method import PhysicsMethod
    from hyperbones.training.loss import physics_terms
    from hyperbones.physics.hard_contact import QUERY_DISTANCE

    garment, rest_vertices = draped_garment("tshirt", body, vertices=1000)
    method = PhysicsMethod(garment, body, rest_vertices, device="cpu", iterations=30)
    still = body.rest_vertices  # the draped garment's own body, held still
    proximity = BodyProximity(method.body_faces)
    proximity.update(still)
    start = garment.vertices + torch.tensor([0.0, 0.0, 0.01])  # lifted 1 cm: gravity has work to do
    velocities = torch.zeros_like(start)
    nearest = proximity.query(start, max_distance=QUERY_DISTANCE)

    def energy(x):
        return float(sum(physics_terms(x, start, velocities, method.rest, nearest, still,
                                       still, method.body_faces, method.collision_weight,
                                       1 / 30).values()))

    guess = start + velocities
    solved = method._minimise(guess, start, velocities, nearest, still, still, 1 / 30)
    assert energy(solved) < energy(guess) - 1e-6
