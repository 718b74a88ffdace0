"""EpisodeBatch: three episodes (templates, resolutions, fabrics, body shapes) as one garment on
one multi-body give each episode what it gets alone: the teacher's step, the physics terms,
the hard contact, and Warp's nearest faces."""

import pytest
import torch

from hyperbones.body.shape import BodyShape
from hyperbones.geometry.proximity import BodyProximity
from hyperbones.geometry.surface import closest_points_on_faces
from hyperbones.geometry.torch_proximity import TorchProximity
from hyperbones.models.cloth_graph import build_graph, internal_acceleration
from hyperbones.models.teacher import Teacher, TrunkConfig, teacher_step
from hyperbones.physics.energies import COLLISION_EPSILON
from hyperbones.physics.hard_contact import QUERY_DISTANCE, constrain_step
from hyperbones.physics.material import Material, material_features
from hyperbones.training.config import DataConfig
from hyperbones.training.data import TeacherData
from hyperbones.training.episode_batch import EpisodeBatch
from hyperbones.training.loss import physics_terms

SPECS = [  # template, vertices, body, fabric
    ("tshirt", 1000, BodyShape(), Material()),
    ("pants", 1300, BodyShape(gender=0.9, weight=0.8, height=0.3),
     Material(lame_mu=40000.0, lame_lambda=20000.0, density=0.4, bending=1e-4)),
    ("long-skirt", 1100, BodyShape(gender=0.1, muscle=0.8, height=0.8, proportions=0.3),
     Material(lame_mu=18000.0, lame_lambda=80000.0, density=0.1, bending=5e-7)),
]
MATERIAL_COLUMNS = slice(13, 17)  # velocity 3, normal 3, kind 3, prescribed 3, mass 1, then μ, λ, k_b, ρ


@pytest.fixture(scope="module")
def episodes(body):
    """Three episodes of three walk frames: (identity, body (3,Vb,3), lbs (3,V,3)) each."""
    out = []
    for seed, (name, vertices, shape, material) in enumerate(SPECS):
        data = TeacherData(DataConfig(templates=(name,), resolutions=(vertices,), train_clips=(), builtins=("walk",),
                                      hold_seconds=0.0), seed=seed)
        episode = data.sample_episode(1, data.identity_for(name, vertices, shape, material))
        out.append((episode.identity, episode.body_vertices.float(), episode.garment_lbs.float()))
    return out


@pytest.fixture(scope="module")
def step(episodes, body):
    """One teacher step t=1 -> 2 of every episode, alone and as a batch: a dict of both sides."""
    torch.manual_seed(0)
    model = Teacher(TrunkConfig(latent=16, blocks=2)).eval()
    batch = EpisodeBatch.of([identity for identity, _, _ in episodes], body.faces)
    generator = torch.Generator().manual_seed(1)
    states = []
    for identity, bodies, lbs in episodes:
        noise = 0.003 * torch.randn(lbs[1].shape, generator=generator)
        positions = torch.where(identity.topology.pinned_mask[:, None], lbs[1], lbs[1] + noise)
        states.append((positions, lbs[1] - lbs[0]))
    alone = []
    with torch.no_grad():
        for (identity, bodies, lbs), (positions, velocities) in zip(episodes, states):
            proximity = TorchProximity(body.faces)
            proximity.update(bodies[1])
            nearest = proximity.query(positions, max_distance=QUERY_DISTANCE)
            x, v = teacher_step(model, identity.topology, identity.rest, positions, velocities, lbs[2], bodies[1],
                                bodies[2], body.faces, nearest, 1.0 / 30.0)
            alone.append(dict(proximity=proximity, nearest=nearest, x=x, v=v, positions=positions,
                              velocities=velocities))
        proximity = batch.proximity(search="torch")
        body_now, body_next = (batch.multi_body([bodies[k] for _, bodies, _ in episodes]) for k in (1, 2))
        proximity.update(body_now)
        positions, velocities = (torch.cat([state[k] for state in states]) for k in (0, 1))
        pinned_next = torch.cat([lbs[2] for _, _, lbs in episodes])
        nearest = proximity.query(positions, max_distance=QUERY_DISTANCE)
        x, v = teacher_step(model, batch.topology, batch.rest, positions, velocities, pinned_next, body_now, body_next,
                            batch.body_faces, nearest, 1.0 / 30.0)
    together = dict(proximity=proximity, nearest=nearest, x=x, v=v, positions=positions, velocities=velocities,
                    body_now=body_now, body_next=body_next, pinned_next=pinned_next)
    return batch, alone, together


def test_the_batch_is_the_garments_one_after_another(episodes, body, step):
    batch, _, _ = step
    identities = [identity for identity, _, _ in episodes]
    sizes = [identity.rest.num_vertices for identity in identities]
    assert batch.sizes == tuple(sizes) and batch.vertex_offsets.tolist() == [0, sizes[0], sum(sizes[:2]), sum(sizes)]
    assert batch.body_faces.shape == (3 * len(body.faces), 3)
    assert torch.equal(batch.body_faces[len(body.faces):2 * len(body.faces)], body.faces + body.num_vertices)
    for b, (identity, piece) in enumerate(zip(identities, batch.split(batch.rest.vertex_masses))):
        assert torch.equal(piece, identity.rest.vertex_masses)
        assert bool((batch.episode_of_vertex[batch.vertex_offsets[b]:batch.vertex_offsets[b + 1]] == b).all())
    faces = batch.rest.faces[len(identities[0].rest.faces):][:len(identities[1].rest.faces)]
    assert torch.equal(faces, identities[1].rest.faces + sizes[0])
    material = batch.rest.material
    assert material.lame_mu.shape == batch.rest.face_areas.shape
    assert material.bending.shape == batch.rest.hinge_lengths.shape
    assert float(material.lame_mu[-1]) == SPECS[2][3].lame_mu
    assert float(material.bending[0]) == pytest.approx(Material().bending)
    assert batch.limiter.difference.shape[0] == sum(len(identity.limiter.edges) for identity in identities)


def test_one_batched_teacher_step_moves_each_garment_as_alone(step):
    batch, alone, together = step
    for single, x, v in zip(alone, batch.split(together["x"]), batch.split(together["v"])):
        torch.testing.assert_close(x, single["x"], atol=1e-5, rtol=0)
        torch.testing.assert_close(v, single["v"], atol=1e-5, rtol=0)
    assert float((together["x"] - together["positions"]).norm(dim=-1).max()) > 1e-3  # the garments moved
    # Each node reads its own episode's fabric; body node u is on body u // Vb.
    graph = build_graph(batch.topology, together["positions"], together["velocities"], together["pinned_next"],
                        together["body_now"], together["body_next"], batch.body_faces, together["nearest"],
                        internal_acceleration=internal_acceleration(together["positions"], batch.rest))
    features = torch.tensor([material_features(material) for _, _, _, material in SPECS])
    material = graph.node_features[:, MATERIAL_COLUMNS]
    assert torch.equal(material[:graph.num_garment], features[batch.episode_of_vertex])
    world = graph.edge_sets["world"]
    episode_of_receiver = batch.episode_of_vertex[world.receivers]
    assert set(episode_of_receiver.tolist()) == {0, 1, 2}
    body_of_corner = batch.body_faces[together["nearest"].face[world.receivers]] // batch.num_body_vertices
    assert bool((body_of_corner == episode_of_receiver[:, None]).all())  # world edges stay on the own body
    assert torch.equal(material[world.senders], features[episode_of_receiver])


def test_a_batch_of_one_steps_bit_for_bit_as_the_identity_alone(episodes, body, step):
    _, alone, _ = step
    identity, bodies, lbs = episodes[1]
    one, single = EpisodeBatch.of([identity], body.faces), alone[1]
    torch.manual_seed(0)
    model = Teacher(TrunkConfig(latent=16, blocks=2)).eval()
    with torch.no_grad():
        x, _ = teacher_step(model, one.topology, one.rest, single["positions"], single["velocities"], lbs[2],
                            one.multi_body([bodies[1]]), one.multi_body(bodies[2:3]), one.body_faces,
                            single["nearest"], 1.0 / 30.0)
    assert torch.equal(x, single["x"])


def test_the_batchs_physics_terms_are_the_sums_of_the_episodes(episodes, body, step):
    batch, alone, together = step
    x = together["x"].clone().requires_grad_(True)
    terms = physics_terms(x, together["positions"], together["velocities"], batch.rest, together["nearest"],
                          together["body_now"], together["body_next"], batch.body_faces, 5e5, 1.0 / 30.0)
    gradient = torch.autograd.grad(sum(terms.values()), x)[0]
    singles, gradients = [], []
    for (identity, bodies, _), single in zip(episodes, alone):
        x_alone = single["x"].clone().requires_grad_(True)
        singles.append(physics_terms(x_alone, single["positions"], single["velocities"], identity.rest,
                                     single["nearest"], bodies[1], bodies[2], body.faces, 5e5, 1.0 / 30.0))
        gradients.append(torch.autograd.grad(sum(singles[-1].values()), x_alone)[0])
    for name, value in terms.items():
        expected = sum(single[name] for single in singles)
        torch.testing.assert_close(value.detach(), expected.detach(), rtol=1e-4, atol=1e-9)
    assert all(float(terms[name].detach()) != 0 for name in ("stretching", "bending", "gravity", "inertia"))
    for piece, expected in zip(batch.split(gradient), gradients):
        torch.testing.assert_close(piece, expected, rtol=1e-4, atol=1e-6 * float(expected.abs().max()))


def test_constrain_step_on_the_batch_gives_each_episode_its_own_result(episodes, step):
    batch, alone, together = step
    # Garment 1 is shoved 1.5 cm into its body, so its contact rounds run on after the others stop.
    shove = torch.zeros_like(together["x"])
    first, last = batch.vertex_offsets[1:3].tolist()
    centre = together["body_next"][batch.num_body_vertices:2 * batch.num_body_vertices].mean(0)
    towards = centre - together["x"][first:last]
    shove[first:last] = 0.015 * towards / towards.norm(dim=-1, keepdim=True)
    raw = together["x"] + shove
    x, v = constrain_step(raw, together["v"] + shove, batch.limiter, together["proximity"], together["nearest"],
                          together["body_next"], ~batch.topology.pinned_mask, COLLISION_EPSILON, QUERY_DISTANCE,
                          vertex_garment=batch.episode_of_vertex)
    for (identity, bodies, _), single, raw_b, v_b, x_b, shove_b in zip(
            episodes, alone, batch.split(raw), batch.split(v), batch.split(x), batch.split(shove)):
        expected_x, expected_v = constrain_step(raw_b, single["v"] + shove_b, identity.limiter, single["proximity"],
                                                single["nearest"], bodies[2], ~identity.topology.pinned_mask,
                                                COLLISION_EPSILON, QUERY_DISTANCE)
        torch.testing.assert_close(x_b, expected_x, atol=1e-5, rtol=0)
        torch.testing.assert_close(v_b, expected_v, atol=1e-5, rtol=0)
    assert float((x - raw).norm(dim=-1).max()) > 0.01  # contact moved the shoved garment
    # Without the garment ids the others take the shoved garment's extra limiter passes.
    ungrouped, _ = constrain_step(raw, together["v"] + shove, batch.limiter, together["proximity"], together["nearest"],
                                  together["body_next"], ~batch.topology.pinned_mask, COLLISION_EPSILON, QUERY_DISTANCE)
    assert float((ungrouped - x).norm(dim=-1).max()) > 1e-3


def test_batched_queries_find_warps_faces_on_each_episodes_own_body(episodes, body, step):
    batch, _, together = step
    ranges = torch.linspace(0.02, 0.1, batch.num_vertices)  # one range per point
    proximity = batch.proximity(search="torch")
    proximity.update(together["body_now"].reshape(3, -1, 3))
    ours = proximity.query(together["positions"], max_distance=ranges)
    assert ours.face.shape == (batch.num_vertices,) and ours.point.shape == (batch.num_vertices, 3)
    assert not bool(ours.found.all())  # both sides of the ranges are exercised
    warp = BodyProximity(body.faces)
    for b, ((_, bodies, _), positions, limits) in enumerate(zip(episodes, batch.split(together["positions"]),
                                                               batch.split(ranges))):
        face, point, distance = (piece[b] for piece in (batch.split(ours.face), batch.split(ours.point),
                                                        batch.split(ours.signed_distance)))
        alone = TorchProximity(body.faces)
        alone.update(bodies[1])
        exact = alone.query(positions, max_distance=limits)  # the search the batch wraps, on this body alone
        assert torch.equal(face, torch.where(exact.found, exact.face + b * len(body.faces), -1))
        assert torch.equal(point, exact.point) and torch.equal(distance, exact.signed_distance)
        warp.update(bodies[1])
        expected = warp.query(positions, max_distance=limits)
        found = expected.found
        assert torch.equal(face >= 0, found) and int(found.sum()) > 100
        torch.testing.assert_close(distance[found], expected.signed_distance[found], atol=1e-5, rtol=0)
        # Faces differ where the nearest point lies on both (a shared edge or corner) and, as for
        # ``TorchProximity`` alone, where two skin points tie in float32.
        ties = (point - expected.point).norm(dim=-1)[found] > 1e-5
        assert int(ties.sum()) <= 0.005 * int(found.sum())
        assert bool(((distance - expected.signed_distance)[found][ties].abs() <= 1e-6).all())
        on_warps = closest_points_on_faces(point.double(), bodies[1].double(), body.faces, expected.face)[found]
        shared = (on_warps - point[found].double()).norm(dim=-1) <= 1e-5
        assert bool((shared | ties).all())
        assert float((face[found] - b * len(body.faces) == expected.face[found]).float().mean()) > 0.5


def test_on_the_cpu_the_batch_asks_warp_body_by_body(episodes, body, step):
    """The "auto" search on a CPU with Warp: one Warp search per body, answers numbered in the
    multi-body's faces; the same as each body's own Warp search, and within 1e-5 m of the torch search's."""
    batch, _, together = step
    ranges = torch.linspace(0.02, 0.1, batch.num_vertices)
    proximity = batch.proximity()
    assert proximity.backend == "warp"
    proximity.update(together["body_now"])
    ours = proximity.query(together["positions"], max_distance=ranges)
    torch_search = batch.proximity(search="torch")
    torch_search.update(together["body_now"])
    theirs = torch_search.query(together["positions"], max_distance=ranges)
    assert torch.equal(ours.found, theirs.found) and int(ours.found.sum()) > 100
    torch.testing.assert_close(ours.signed_distance[ours.found], theirs.signed_distance[ours.found], atol=1e-5, rtol=0)
    for b, ((_, bodies, _), positions, limits, face) in enumerate(zip(
            episodes, batch.split(together["positions"]), batch.split(ranges), batch.split(ours.face))):
        warp = BodyProximity(body.faces)  # built on this body, as the batch's (a refit tree may break ties otherwise)
        warp.update(bodies[1])
        expected = warp.query(positions, max_distance=limits)
        assert torch.equal(face, torch.where(expected.found, expected.face + b * len(body.faces), -1))
