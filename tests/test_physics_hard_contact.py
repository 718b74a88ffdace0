"""Hard contact after a teacher step, on the real body: cloth goes back out on the side of the
skin it came from, inside the strain limiter's sweeps; pinned cloth stays; moves become velocity."""

import torch

from hyperbones.geometry.proximity import BodyProximity
from hyperbones.physics.contact_planes import ContactPlanes
from hyperbones.physics.hard_contact import CONTACT_ROUNDS, constrain_step
from hyperbones.physics.strain_limit import StrainLimiter

MARGIN = 2e-3


def _chest_patch(body, proximity):
    """A small triangle 5 mm in front of the chest: (3,3) positions, (3,) skin normals, its limiter."""
    v = body.rest_vertices
    chest = torch.nonzero((v[:, 2] > 1.15) & (v[:, 2] < 1.3) & (v[:, 0].abs() < 0.03)).squeeze(1)
    front = chest[v[chest, 1].argmin()] if v[chest, 1].mean() > v[:, 1].mean() else chest[v[chest, 1].argmax()]
    skin = v[front]
    normal = proximity.query(skin[None], max_distance=0.1).normal[0]
    side = torch.linalg.cross(normal, torch.tensor([0.0, 0.0, 1.0]))
    side = side / side.norm()
    positions = skin + 0.005 * normal + 0.01 * torch.stack([torch.zeros(3), side, torch.tensor([0.0, 0.0, 1.0])])
    edges = torch.tensor([[0, 1], [1, 2], [0, 2]])
    rest_lengths = (positions[edges[:, 1]] - positions[edges[:, 0]]).norm(dim=-1)
    return positions, normal, edges, rest_lengths


def test_a_deep_sweep_puts_cloth_back_on_the_side_it_came_from(body):
    """The chest moves 15 cm forward in one step through cloth 5 mm in front of it: a push to
    the nearest skin point would send the cloth out of the back; the tracked face keeps it in front."""
    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    positions, normal, edges, rest_lengths = _chest_patch(body, proximity)
    limiter = StrainLimiter.build(edges, rest_lengths, torch.full((3,), 1e-3), torch.zeros(3, dtype=torch.bool))
    nearest_before = proximity.query(positions, max_distance=0.1)
    assert (nearest_before.signed_distance > 0).all()
    sweep = 0.15 * normal
    body_after = body.rest_vertices + sweep
    velocities = torch.zeros_like(positions)
    inside_after = BodyProximity(body.faces)
    inside_after.update(body_after)
    deep = inside_after.query(positions, max_distance=0.2)
    assert (deep.signed_distance < -0.02).all()  # inside, and nearest to the back of the chest:
    assert ((deep.normal * normal).sum(-1) < 0).all()  # a nearest-point push would go out of the back
    moved, moved_velocities = constrain_step(positions, velocities, limiter, proximity, nearest_before, body_after,
                                             torch.ones(3, dtype=torch.bool), MARGIN, 0.2)
    along = ((moved - positions) * normal).sum(-1)
    torch.testing.assert_close(along, torch.full((3,), 0.15 + 0.0), atol=0.01, rtol=0)  # carried forward
    after = proximity.query(moved, max_distance=0.1).signed_distance  # the BVH now holds body_after
    assert (after > 0).all() and (after < 0.01).all()
    torch.testing.assert_close(moved_velocities, velocities + (moved - positions))  # the move is velocity


def test_pinned_cloth_stays_and_cloth_outside_is_left_alone(body):
    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    positions, normal, edges, rest_lengths = _chest_patch(body, proximity)
    movable = torch.tensor([False, True, True])
    limiter = StrainLimiter.build(edges, rest_lengths, torch.full((3,), 1e-3), ~movable)
    nearest_before = proximity.query(positions, max_distance=0.1)
    body_after = body.rest_vertices + 0.02 * normal  # 2 cm forward: the cloth ends 1.5 cm inside
    moved, _ = constrain_step(positions, torch.zeros_like(positions), limiter, proximity, nearest_before, body_after,
                              movable, MARGIN, 0.1)
    torch.testing.assert_close(moved[0], positions[0], atol=0, rtol=0)
    assert (proximity.query(moved[1:], max_distance=0.1).signed_distance > 0).all()  # the rest went out
    # Cloth already outside and inside its band is not touched (the body stays where it is).
    proximity.update(body.rest_vertices)
    kept, _ = constrain_step(positions, torch.zeros_like(positions), limiter, proximity, nearest_before,
                             body.rest_vertices, torch.ones(3, dtype=torch.bool), MARGIN, 0.1)
    torch.testing.assert_close(kept, positions, atol=0, rtol=0)


def test_planes_only_push_outwards():
    planes = ContactPlanes(torch.tensor([0, 2]), torch.zeros(2, 3), torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))
    points = torch.tensor([[0.3, 0.1, -0.02], [5.0, 5.0, -5.0], [-0.01, 0.4, 0.2]])
    projected = planes.project(points)
    torch.testing.assert_close(projected, torch.tensor([[0.3, 0.1, 0.0], [5.0, 5.0, -5.0], [0.0, 0.4, 0.2]]))
    torch.testing.assert_close(planes.project(projected), projected)  # on or in front of a plane: kept


def _belt(body, proximity, outward: torch.Tensor, height: float = 1.0, count: int = 32):
    """(count,3) a horizontal loop around the waist at ``outward`` (count,) metres outside the
    skin, found by walking in from 40 cm along each direction until the first point inside."""
    v = body.rest_vertices
    waist = v[((v[:, 2] - height).abs() < 0.01) & (v[:, 0].abs() < 0.2)]
    centre = waist[:, :2].mean(0)
    angle = torch.arange(count) * 2 * torch.pi / count
    directions = torch.stack([angle.cos(), angle.sin()], 1)
    radii = torch.linspace(0.4, 0.0, 401)
    probes = centre + radii[:, None, None] * directions[None]  # (401,count,2)
    probes = torch.cat([probes.reshape(-1, 2), torch.full((probes.shape[0] * count, 1), height)], 1)
    inside = proximity.query(probes, max_distance=0.5).signed_distance.reshape(len(radii), count) < 0
    skin_radius = radii[inside.float().argmax(0)]
    return torch.cat([centre + (skin_radius + outward)[:, None] * directions, torch.full((count, 1), height)], 1)


def test_cloth_the_limiter_pulls_into_the_body_gets_planes_and_the_slack_comes_from_free_cloth(body):
    """A stretched belt around the waist, snug on one side, 8 cm out on the other: the limiter
    shrinks it into the snug side; with a plane there the slack comes from the loose side and
    the belt ends much less stretched than a nearest-point push after one pass leaves it."""
    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    count = 32
    angle = torch.arange(count) * 2 * torch.pi / count
    belt = _belt(body, proximity, torch.where(angle.cos() > 0, 0.004, 0.08))
    assert (proximity.query(belt, max_distance=0.3).signed_distance > 0).all()
    edges = torch.stack([torch.arange(count), (torch.arange(count) + 1) % count], 1)
    rest_lengths = 0.8 * (belt[edges[:, 1]] - belt[edges[:, 0]]).norm(dim=-1)  # 25 % stretched
    limiter = StrainLimiter.build(edges, rest_lengths, torch.full((count,), 1e-3), torch.zeros(count, dtype=torch.bool))
    untracked = proximity.query(belt + 1.0, max_distance=0.1)  # nothing near the skin before the step
    movable = torch.ones(count, dtype=torch.bool)

    def stretch(rounds):
        moved, _ = constrain_step(belt, torch.zeros_like(belt), limiter, proximity, untracked, body.rest_vertices,
                                  movable, MARGIN, 0.3, rounds=rounds)
        assert (proximity.query(moved, max_distance=0.3).signed_distance > 0).all()
        ratio = (moved[edges[:, 1]] - moved[edges[:, 0]]).norm(dim=-1) / rest_lengths
        return float(ratio.max()), float(ratio.mean())

    one_pass, with_rounds = stretch(0), stretch(CONTACT_ROUNDS)
    assert one_pass[0] > 1.3  # the push after one pass stretches the snug side again
    assert with_rounds[0] < one_pass[0] - 0.1 and with_rounds[1] < one_pass[1]


def test_the_work_per_step_is_bounded_whatever_the_input(body, monkeypatch):
    """A bad case: a garment whose every vertex ends the step 3 cm inside the body without having
    been near the skin before it (no tracked planes), its edges pulling it across the torso, so
    that limiter passes leave cloth inside round after round. The step still does at most
    1 + CONTACT_ROUNDS limiter passes (each of the limiter's fixed sweeps) and 2 + CONTACT_ROUNDS
    body queries: the bound on the teacher's cost per frame."""
    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    v = body.rest_vertices
    torso = torch.nonzero((v[:, 2] > 1.0) & (v[:, 2] < 1.35) & (v[:, 0].abs() < 0.12)).squeeze(1)[::7][:60]
    positions = v[torso] - 0.03 * proximity.query(v[torso], max_distance=0.1).normal  # 3 cm under the skin
    count = len(positions)
    edges = torch.stack([torch.arange(count), torch.roll(torch.arange(count), 7)], dim=1)
    limiter = StrainLimiter.build(edges, torch.full((count,), 1e-3), torch.full((count,), 1e-3),
                                  torch.zeros(count, dtype=torch.bool))
    calls = {"limiter": 0, "query": 0}
    project, query = StrainLimiter.project, BodyProximity.query

    def counted(name, function):
        def wrapper(*args, **kwargs):
            calls[name] += 1
            return function(*args, **kwargs)
        return wrapper

    nearest_before = proximity.query(positions + 1.0, max_distance=0.1)  # a metre away before the step
    assert not nearest_before.found.any()
    monkeypatch.setattr(StrainLimiter, "project", counted("limiter", project))
    monkeypatch.setattr(BodyProximity, "query", counted("query", query))
    moved, _ = constrain_step(positions, torch.zeros_like(positions), limiter, proximity, nearest_before,
                              v + 0.01, torch.ones(count, dtype=torch.bool), MARGIN, 0.1)
    assert 2 <= calls["limiter"] <= 1 + CONTACT_ROUNDS  # a second pass ran for the cloth left inside
    assert calls["query"] <= 2 + CONTACT_ROUNDS
    assert torch.isfinite(moved).all()


def test_searches_bounded_by_known_skin_points_answer_as_the_full_ones(body, monkeypatch):
    """constrain_step bounds every body search by a skin point it already knows (the one before
    the step carried onto the body now, then each round's last answer): the step's result is
    the one full-range searches give, with Warp's search and with the torch one."""
    import hyperbones.physics.hard_contact as hard_contact
    from hyperbones.geometry.torch_proximity import TorchProximity

    v = body.rest_vertices
    generator = torch.Generator().manual_seed(3)
    torso = torch.nonzero((v[:, 2] > 0.9) & (v[:, 2] < 1.4)).squeeze(1)[::23][:150]
    probe = BodyProximity(body.faces)
    probe.update(v)
    normal = probe.query(v[torso], max_distance=0.1).normal
    offsets = torch.empty(len(torso), 1).uniform_(-0.03, 0.15, generator=generator)
    positions = v[torso] + offsets * normal  # some inside, some near, some beyond the 10 cm searched
    count = len(positions)
    edges = torch.stack([torch.arange(count), torch.roll(torch.arange(count), 1)], dim=1)
    limiter = StrainLimiter.build(edges, 0.9 * (positions[edges[:, 1]] - positions[edges[:, 0]]).norm(dim=-1),
                                  torch.full((count,), 1e-3), torch.zeros(count, dtype=torch.bool))
    body_before, body_after = v - torch.tensor([0.0, 0.01, 0.0]), v
    movable = torch.ones(count, dtype=torch.bool)
    for search in (BodyProximity, TorchProximity):
        results = []
        for bounded in (True, False):
            if not bounded:
                monkeypatch.setattr(hard_contact, "search_ranges", lambda points, skin, distance: distance)
            proximity = search(body.faces)
            proximity.update(body_before)
            nearest_before = proximity.query(positions - torch.tensor([0.0, 0.01, 0.0]), max_distance=0.1)
            assert nearest_before.found.any() and not nearest_before.found.all()
            results.append(constrain_step(positions, torch.zeros_like(positions), limiter, proximity, nearest_before,
                                          body_after, movable, MARGIN, 0.1)[0])
        monkeypatch.undo()
        assert torch.equal(results[0], results[1]), search.__name__
