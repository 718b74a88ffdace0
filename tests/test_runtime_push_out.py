"""The runtime's contact step: garment vertices inside the body pushed out to the margin."""

import pytest
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.proximity import BodyProximity
from hyperbones.runtime.config import RuntimeConfig
from hyperbones.runtime.push_out import BodyContact
from hyperbones.runtime.edge_projection import EdgeProjection


def test_points_inside_the_body_come_out_and_the_others_stay(body):
    torch.manual_seed(0)
    vertices, faces = body.rest_vertices, body.faces
    proximity = BodyProximity(faces)
    proximity.update(vertices)
    # The torso, where garments touch the body (not the face, hands or feet with their small creases).
    torso = torch.nonzero((vertices[:, 2] > 1.0) & (vertices[:, 2] < 1.35) & (vertices[:, 0].abs() < 0.15)).squeeze(1)
    picked = torso[torch.randperm(len(torso))[:400]]
    normals = proximity.query(vertices[picked], max_distance=0.1).normal
    inside = vertices[picked] - 0.01 * normals   # a centimetre under the skin
    outside = vertices[picked] + 0.03 * normals  # three centimetres off it
    contact = BodyContact(faces, characters=1, config=RuntimeConfig(contact_margin=0.002))
    clear = proximity.query(outside, max_distance=0.1).signed_distance >= 0.002  # not in another body part
    assert int(clear.sum()) > 300
    (pushed,) = contact([torch.cat([inside, outside])], vertices[None])
    after = proximity.query(pushed, max_distance=0.1).signed_distance
    assert float(after[:400].min()) > 0.0015  # every one is out, at about the margin
    assert torch.equal(pushed[400:][clear], outside[clear])
    with pytest.raises(ParameterError, match="one posed body per character"):
        contact([inside, inside], torch.stack([vertices, vertices]))


def _grid(rows: int, cols: int, spacing: float) -> tuple[torch.Tensor, torch.Tensor]:
    """A flat (rows×cols) sheet in the XZ plane, two triangles per cell."""
    x, z = torch.meshgrid(torch.arange(cols) * spacing, torch.arange(rows) * spacing, indexing="xy")
    vertices = torch.stack([x.flatten(), torch.zeros(rows * cols), z.flatten()], dim=1)
    index = torch.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = index[:-1, :-1].flatten(), index[:-1, 1:].flatten(), index[1:, :-1].flatten(), index[1:, 1:].flatten()
    return vertices, torch.cat([torch.stack([a, b, d], 1), torch.stack([a, d, c], 1)])


def test_edge_projection_pulls_a_stretched_sheet_back_and_keeps_it_out_of_the_body(body):
    vertices, faces = body.rest_vertices, body.faces
    sheet, sheet_faces = _grid(12, 12, 0.02)
    # 15 cm in front of the chest (the A-pose faces −Y), then stretched by 15 % across.
    front = float(vertices[(vertices[:, 2] > 1.2) & (vertices[:, 2] < 1.3) & (vertices[:, 0].abs() < 0.05), 1].min())
    placed = sheet + torch.tensor([-0.11, front - 0.15, 1.14])
    stretched = placed * torch.tensor([1.15, 1.0, 1.0]) - torch.tensor([placed[:, 0].mean() * 0.15, 0, 0])
    projection = EdgeProjection(placed, sheet_faces)
    plain = BodyContact(faces, characters=1, config=RuntimeConfig(contact_margin=0.002))
    limited = BodyContact(faces, characters=1, projections=[projection], config=RuntimeConfig(contact_margin=0.002))
    first, second = projection.edges[:, 0], projection.edges[:, 1]

    def strain(points):
        return ((points[second] - points[first]).norm(dim=1) / projection.rest_lengths - 1).abs().mean()

    (kept,) = plain([stretched], vertices[None])
    (pulled,) = limited([stretched], vertices[None])
    assert float(strain(kept)) > 0.05
    assert float(strain(pulled)) < 0.5 * float(strain(kept))
    pressed = pulled.clone()
    pressed[:, 1] = front + 0.01  # flattened onto a plane a centimetre behind the chest's front
    proximity = BodyProximity(faces)
    proximity.update(vertices)
    assert float(proximity.query(pressed, max_distance=0.1).signed_distance.min()) < -0.005
    (out,) = limited([pressed], vertices[None])
    assert float(proximity.query(out, max_distance=0.1).signed_distance.min()) > 0.0
    with pytest.raises(ParameterError, match="edge projections"):
        BodyContact(faces, characters=2, projections=[projection])


def test_skin_motion_is_how_far_the_skin_under_each_vertex_moved(body):
    vertices, faces = body.rest_vertices, body.faces
    proximity = BodyProximity(faces)
    proximity.update(vertices)
    torso = torch.nonzero((vertices[:, 2] > 1.0) & (vertices[:, 2] < 1.35) & (vertices[:, 0].abs() < 0.15)).squeeze(1)
    near = vertices[torso[:50]] + 0.01 * proximity.query(vertices[torso[:50]], max_distance=0.1).normal
    far = vertices[torso[:5]] + torch.tensor([0.0, -0.5, 0.0])  # half a metre in front: beyond every query
    contact = BodyContact(faces, characters=1, config=RuntimeConfig(contact_margin=0.002))
    assert contact.skin_motion(0, vertices) is None  # nothing found yet
    contact([torch.cat([near, far])], vertices[None])
    # The body bends: each vertex moves by an amount of its own, so the skin stretches too.
    bent = vertices + torch.stack([0.05 * vertices[:, 2], 0.02 * vertices[:, 0], torch.zeros(len(vertices))], dim=1)
    moved, distance = contact.skin_motion(0, bent)
    nearest = proximity.query(near, max_distance=0.1)
    corners = faces[nearest.face]
    expected = ((bent[corners] - vertices[corners]) * nearest.barycentric[..., None]).sum(1)
    assert torch.allclose(moved[:50], expected, atol=1e-5)
    assert float(moved[:50].norm(dim=1).min()) > 0.04  # the torso moved some 5 cm sideways
    assert torch.equal(moved[50:], torch.zeros(5, 3)) and bool(torch.isinf(distance[50:]).all())
    assert torch.allclose(distance[:50], nearest.signed_distance, atol=1e-6)  # a centimetre or a little less
    contact.forget()
    assert contact.skin_motion(0, bent) is None


def test_a_vertex_pushed_out_beyond_the_body_comes_back_to_its_neighbours_side(body):
    """A limb that went through the cloth leaves a vertex nearest the far side: pushed out
    there, its edges would reach round the body. Untangling brings it back in front."""
    vertices, faces = body.rest_vertices, body.faces
    chest = (vertices[:, 2] > 1.2) & (vertices[:, 2] < 1.3) & (vertices[:, 0].abs() < 0.05)
    front, back = float(vertices[chest, 1].min()), float(vertices[chest, 1].max())
    sheet, sheet_faces = _grid(7, 7, 0.02)
    placed = sheet + torch.tensor([-0.06, front - 0.01, 1.19])  # a centimetre in front of the chest
    middle = 24  # the sheet's centre vertex
    tangled = placed.clone()
    tangled[middle, 1] = back - 0.02  # two centimetres under the skin of the back
    projection = EdgeProjection(placed, sheet_faces)
    kept = BodyContact(faces, characters=1, projections=[projection],
                       config=RuntimeConfig(contact_margin=0.002, untangle=False))
    untangled = BodyContact(faces, characters=1, projections=[projection], config=RuntimeConfig(contact_margin=0.002))
    (behind,) = kept([tangled], vertices[None])
    (back_in_front,) = untangled([tangled], vertices[None])
    assert float(behind[middle, 1]) > back - 0.01  # pushed out of the back, the width of the body away
    assert float(back_in_front[middle, 1]) < front  # in front of the chest with its neighbours
    proximity = BodyProximity(faces)
    proximity.update(vertices)
    assert float(proximity.query(back_in_front, max_distance=0.1).signed_distance.min()) > 0.0
    others = torch.arange(len(placed)) != middle
    # Left behind, the vertex's edges drag its neighbours towards the chest; brought back, they stay put.
    assert float((behind[others] - placed[others]).norm(dim=1).max()) > 0.01
    assert float((back_in_front[others] - placed[others]).norm(dim=1).max()) < 0.003



def _sheet_bent_round_the_chest(vertices: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A 16×16 sheet 3 cm in front of the chest of the rest body (Vb,3): its (256,3) flat rest
    positions, (450,3) faces, and (256,3) positions bent round the chest, the middle columns
    a centimetre inside it, the sides 1-5 cm in front of it."""
    sheet, sheet_faces = _grid(16, 16, 0.015)
    front = float(vertices[(vertices[:, 2] > 1.2) & (vertices[:, 2] < 1.3) & (vertices[:, 0].abs() < 0.05), 1].min())
    placed = sheet + torch.tensor([-0.11, front - 0.03, 1.1])
    bent = placed + torch.stack([torch.zeros(len(sheet)), 0.04 - 0.4 * (sheet[:, 0] - 0.11).square() * 8,
                                 torch.zeros(len(sheet))], 1)
    return placed, sheet_faces, bent


def test_a_search_gap_searches_fewer_points_and_still_pushes_every_one_out(body):
    """``round_search_gap``: after a projection round only vertices that may be nearer than the
    gap are searched again; the others keep their faces, yet none is left inside the body."""
    vertices, faces = body.rest_vertices, body.faces
    placed, sheet_faces, bent = _sheet_bent_round_the_chest(vertices)
    projection = EdgeProjection(placed, sheet_faces)
    proximity = BodyProximity(faces)
    proximity.update(vertices)
    before = proximity.query(bent, max_distance=0.2).signed_distance
    assert float(before.min()) < -0.005 and float(before.max()) > 0.02  # inside and well clear, both
    searched, out = {}, {}
    for gap in (0.0, 0.01):  # 0: no gap, every vertex within reach is searched (exact)
        contact = BodyContact(faces, characters=1, projections=[projection],
                              config=RuntimeConfig(round_search_gap=gap, contact_margin=0.002))
        search, counted = contact.proximities[0], []
        query, push_out = search.query, search.push_out  # points searched, one at a time or pushed in one launch
        search.query = lambda points, max_distance=1.0: (counted.append(len(points)), query(points, max_distance))[1]
        search.push_out = lambda points, *settings: (counted.append(len(points)), push_out(points, *settings))[1]
        contact([bent], vertices[None])  # a first frame, then a second one from its records
        counted.clear()
        (out[gap],) = contact([bent], vertices[None])
        searched[gap] = sum(counted)
    assert searched[0.01] < searched[0.0], searched
    for gap, garment in out.items():
        assert float(proximity.query(garment, max_distance=0.2).signed_distance.min()) > 0.0, gap


def _box(low: list[float], high: list[float]) -> tuple[torch.Tensor, torch.Tensor]:
    """An axis-aligned box: 8 corners and 12 triangles wound outward."""
    corners = torch.tensor([[high[0] if i & 1 else low[0], high[1] if i & 2 else low[1], high[2] if i & 4 else low[2]]
                            for i in range(8)])
    faces = torch.tensor([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                          [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
    return corners, faces


def _two_boxes_and_points_between() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Two boxes 1.5 mm apart along x (16 corners, 24 faces) and three points in the gap or
    just inside the left box (3,3)."""
    left, left_faces = _box([-0.1, -0.1, -0.1], [0.0, 0.1, 0.1])
    right, right_faces = _box([0.0015, -0.1, -0.1], [0.1015, 0.1, 0.1])
    garment = torch.tensor([[0.0004, 0.0, 0.0], [0.0011, 0.02, 0.0], [-0.001, 0.0, 0.03]])
    return torch.cat([left, right]), torch.cat([left_faces, right_faces + 8]), garment


def test_a_vertex_between_two_body_parts_closer_than_twice_the_margin_stops_halfway():
    """Two boxes 1.5 mm apart (an arm skinned against the chest leaves such gaps): pushed 2 mm off
    one, a vertex is inside the other, and off that back inside the first, for every round there
    is. The push-out sees the faces face each other and leaves it halfway, outside both."""
    vertices, faces, garment = _two_boxes_and_points_between()
    contact = BodyContact(faces, characters=1, config=RuntimeConfig(contact_margin=0.002, push_rounds=64))
    (pushed,) = contact([garment], vertices[None])
    # Halfway across the gap, 0.75 mm outside both boxes (the query's own sign is a coin toss
    # there: the two faces are exactly as near), and moved only across it.
    assert torch.allclose(pushed[:, 0], torch.full((3,), 0.00075), atol=1e-6)
    assert torch.allclose(pushed[:, 1:], garment[:, 1:], atol=1e-8)


def test_the_push_out_in_one_warp_launch_is_the_torch_rounds(body):
    """``BodyProximity.push_out`` (Warp, one vertex a thread) against the rounds over all vertices
    in torch: a sheet bent through the chest, then projected and searched again, over two
    frames (so that the second starts from the first's skin points), and a vertex between two
    body parts: the same garments and records."""
    vertices, faces = body.rest_vertices, body.faces
    placed, sheet_faces, bent = _sheet_bent_round_the_chest(vertices)
    projection = EdgeProjection(placed, sheet_faces)
    outputs, records = {}, {}
    for fused in (True, False):
        contact = BodyContact(faces, characters=1, projections=[projection], config=RuntimeConfig(contact_margin=0.002))
        contact.fused = fused
        contact([bent], vertices[None])
        (outputs[fused],) = contact([bent + 0.004], vertices[None])
        records[fused] = contact.last_nearest[0]
    assert int(((outputs[False] - bent - 0.004).norm(dim=1) > 0.005).sum()) > 20  # the rounds had work to do
    assert torch.allclose(outputs[True], outputs[False], atol=1e-6, rtol=0)
    for name in ("face", "point", "normal", "signed_distance"):
        assert torch.allclose(getattr(records[True], name).float(), getattr(records[False], name).float(),
                              atol=1e-6, rtol=0), name
    boxes, box_faces, garment = _two_boxes_and_points_between()
    pushed = {}
    for fused in (True, False):
        contact = BodyContact(box_faces, characters=1, config=RuntimeConfig(contact_margin=0.002, push_rounds=64))
        contact.fused = fused
        (pushed[fused],) = contact([garment], boxes[None])
    assert torch.allclose(pushed[True], pushed[False], atol=1e-7, rtol=0)
