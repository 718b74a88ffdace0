import pytest
import torch

from hyperbones.geometry.proximity import BodyProximity
from hyperbones.geometry.surface import (closest_points_on_faces, face_planes, is_closed_surface, signed_distance,
                                         surface_points)
from hyperbones.physics.energies import collision_energy

F64 = torch.float64


def icosphere(subdivisions: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A unit sphere: an icosahedron split ``subdivisions`` times, faces wound outward."""
    t = (1 + 5**0.5) / 2
    vertices = torch.tensor([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                             [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=F64)
    faces = torch.tensor([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                          [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                          [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    vertices = vertices / vertices.norm(dim=-1, keepdim=True)
    for _ in range(subdivisions):
        edges = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).sort(dim=-1).values
        unique, inverse = torch.unique(edges, dim=0, return_inverse=True)
        midpoints = torch.nn.functional.normalize(vertices[unique[:, 0]] + vertices[unique[:, 1]], dim=-1)
        mid = inverse.reshape(3, -1).T + vertices.shape[0]  # (F,3): midpoints of edges 01, 12, 20
        vertices = torch.cat([vertices, midpoints])
        a, b, c = faces.T
        ab, bc, ca = mid.T
        faces = torch.cat([torch.stack(corners, -1) for corners in
                           ((a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca))])
    return vertices, faces


@pytest.fixture(scope="module")
def sphere():
    return icosphere(4)  # 2562 vertices; flat faces sag at most ~1 mm below the unit sphere


@pytest.fixture()
def sphere_proximity(sphere):
    """A BodyProximity (default sign) fitted to the unit sphere."""
    proximity = BodyProximity(sphere[1])
    proximity.update(sphere[0])
    return proximity


def shell_points(count: int, low: float, high: float, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    directions = torch.nn.functional.normalize(torch.randn(count, 3, dtype=F64, generator=generator), dim=-1)
    return directions * (low + (high - low) * torch.rand(count, 1, dtype=F64, generator=generator))


@pytest.mark.parametrize("sign", ["normal", "winding"])
def test_sphere_distances_signs_and_outward_normals(sphere, sign):
    vertices, faces = sphere
    proximity = BodyProximity(faces, sign=sign)
    proximity.update(vertices)
    points = shell_points(2000, 0.5, 1.5)
    nearest = proximity.query(points)
    radius = points.norm(dim=-1)
    assert nearest.signed_distance.dtype == F64 and nearest.face.dtype == torch.int64
    assert bool(nearest.found.all())
    assert torch.allclose(nearest.signed_distance, radius - 1.0, atol=1.5e-3)
    clear = (radius - 1.0).abs() > 2e-3  # away from the faceted surface the sign must be exact
    assert torch.equal(nearest.signed_distance[clear] < 0, radius[clear] < 1.0)
    assert ((nearest.normal * points).sum(-1) / radius).min() > 0.99
    assert torch.allclose(nearest.normal.norm(dim=-1), torch.ones(2000, dtype=F64), atol=1e-5)
    on_surface = surface_points(vertices, faces, nearest.face, nearest.barycentric)
    assert torch.allclose(on_surface, nearest.point, atol=1e-6)


def test_auto_sign_picks_normal_for_closed_and_winding_for_open_meshes(sphere):
    vertices, faces = sphere
    assert BodyProximity(faces).sign == "normal" and is_closed_surface(faces)
    upper = faces[vertices[faces].mean(dim=1)[:, 2] > -0.9]  # a sphere with a hole at the bottom
    assert not is_closed_surface(upper)
    proximity = BodyProximity(upper)
    assert proximity.sign == "winding"
    proximity.update(vertices)
    inside = proximity.query(torch.tensor([[0.0, 0.0, -0.5], [0.3, 0.2, 0.1]]))
    assert bool((inside.signed_distance < 0).all())


def test_refit_follows_the_moved_body(sphere, sphere_proximity):
    vertices, faces = sphere
    proximity = sphere_proximity
    points = shell_points(500, 0.8, 1.2, seed=1)
    before = proximity.query(points)
    offset = torch.tensor([3.0, -1.0, 0.5], dtype=F64)
    proximity.update(vertices + offset)
    after = proximity.query(points + offset)
    assert torch.allclose(after.signed_distance, before.signed_distance, atol=1e-5)
    # Near-ties between faces (points deep inside) may flip after float32 rounding.
    same = after.face == before.face
    assert same.float().mean() > 0.95
    assert torch.allclose(after.point[same], before.point[same] + offset, atol=2e-6)
    stale = proximity.query(torch.zeros(1, 3, dtype=F64), max_distance=5.0)  # the old centre: now 2.2 m outside
    assert stale.signed_distance.item() == pytest.approx(offset.norm().item() - 1.0, abs=2e-3)


def test_points_out_of_range_get_no_face(sphere, sphere_proximity):
    vertices, faces = sphere
    proximity = sphere_proximity
    nearest = proximity.query(torch.tensor([[0.0, 0.0, 1.001], [0.0, 0.0, 3.0]]), max_distance=0.1)
    assert nearest.face.tolist()[1] == -1 and nearest.face.tolist()[0] >= 0
    assert proximity.query(torch.zeros(2, 4, 3)).signed_distance.shape == (2, 4)  # leading dims kept
    assert nearest.signed_distance[1] == float("inf") and nearest.normal[1].abs().sum() == 0
    origin, normal = face_planes(vertices, faces, nearest.face)
    assert normal[1].abs().sum() == 0 and signed_distance(nearest.point, vertices, faces, nearest.face)[1] == float("inf")
    with pytest.raises(RuntimeError):
        BodyProximity(faces).query(torch.zeros(1, 3))


def test_torch_signed_distance_matches_warp_near_the_surface_and_has_gradients(sphere, sphere_proximity):
    vertices, faces = sphere
    proximity = sphere_proximity
    points = shell_points(1000, 0.99, 1.01, seed=2)
    nearest = proximity.query(points)
    interior = (nearest.barycentric > 1e-3).all(dim=-1)  # closest point inside its face: plane = triangle
    assert interior.float().mean() > 0.8
    body = vertices.clone().requires_grad_(True)
    queries = points.clone().requires_grad_(True)
    distance = signed_distance(queries, body, faces, nearest.face)
    assert torch.allclose(distance[interior], nearest.signed_distance[interior], atol=1e-6)
    assert (distance - nearest.signed_distance).abs().max() < 1e-3
    grad_points, grad_body = torch.autograd.grad(distance.sum(), (queries, body))
    assert torch.allclose(grad_points, nearest.normal, atol=1e-6)  # ∂d/∂x is the face normal
    assert torch.isfinite(grad_body).all() and grad_body.abs().sum() > 0
    few = nearest.face[:5]
    assert torch.autograd.gradcheck(lambda p, b: signed_distance(p, b, faces, few), (queries[:5].detach().requires_grad_(True), body))


def test_collision_energy_from_a_query_penalises_points_inside(sphere, sphere_proximity):
    vertices, faces = sphere
    proximity = sphere_proximity
    points = torch.tensor([[0.0, 0.0, 0.97], [0.0, 0.0, 1.1]], dtype=F64)
    nearest = proximity.query(points)
    origin, normal = face_planes(vertices, faces, nearest.face)
    energy = collision_energy(points, origin, normal, weight=1.0)
    depth = 2e-3 - signed_distance(points, vertices, faces, nearest.face)[0]
    assert energy.item() == pytest.approx(depth.item() ** 3, rel=1e-9) and depth > 0.02


def test_closest_points_on_faces_match_warp_and_a_dense_sampling(sphere, sphere_proximity):
    vertices, faces = sphere
    points = shell_points(500, 0.9, 1.1, seed=3)
    nearest = sphere_proximity.query(points.float(), max_distance=0.5)
    exact = closest_points_on_faces(points, vertices, faces, nearest.face)
    assert exact.dtype == F64
    assert torch.allclose(exact.float(), nearest.point, atol=1e-5)  # Warp's float32 answer
    # Any triangle, any point: nothing on the triangle is closer (its vertex, edge and face regions).
    generator = torch.Generator().manual_seed(1)
    triangle = torch.randn(3, 3, dtype=F64, generator=generator)
    far = torch.randn(1000, 3, dtype=F64, generator=generator) * 2
    found = closest_points_on_faces(far, triangle, torch.tensor([[0, 1, 2]]), torch.zeros(1000, dtype=torch.long))
    u, v = torch.meshgrid(torch.linspace(0, 1, 300, dtype=F64), torch.linspace(0, 1, 300, dtype=F64), indexing="ij")
    inside = (u + v) <= 1
    samples = triangle[0] + u[inside, None] * (triangle[1] - triangle[0]) + v[inside, None] * (triangle[2] - triangle[0])
    gap = (far - found).norm(dim=-1) - torch.cdist(far, samples).min(dim=1).values
    assert float(gap.max()) < 1e-12 and float(gap.min()) > -0.01  # never farther; as close as the sampling


def test_push_outside_moves_only_close_movable_points(sphere_proximity):
    from hyperbones.geometry.surface import push_outside

    proximity = sphere_proximity
    points = torch.tensor([[0.0, 0.0, 0.5], [0.0, 0.0, 1.0005], [0.0, 0.0, 1.5], [0.0, 0.5, 0.0]])
    nearest = proximity.query(points, max_distance=1.0)
    movable = torch.tensor([True, True, True, False])
    pushed = push_outside(points, nearest, 2e-3, movable=movable)
    after = proximity.query(pushed, max_distance=1.0).signed_distance
    assert bool((after[:2] > 1.5e-3).all())  # inside, and 0.5 mm out: both at the margin now
    assert torch.equal(pushed[2], points[2]) and torch.equal(pushed[3], points[3])  # far; not movable


def test_each_query_answers_alone_though_the_buffers_are_shared(sphere_proximity):
    """Queries reuse one set of Warp arrays: an answer stays as it was after later, larger and
    smaller queries, and each equals that of a fresh search structure."""
    big, small = shell_points(3000, 0.9, 1.1, seed=1).float(), shell_points(7, 0.95, 1.05, seed=2).float()
    first = sphere_proximity.query(small, max_distance=0.2)
    kept = [value.clone() for value in (first.face, first.point, first.signed_distance)]
    sphere_proximity.query(big, max_distance=0.2)  # grows the buffers
    again = sphere_proximity.query(small[:3], max_distance=torch.full((3,), 0.2))
    for value, copy in zip((first.face, first.point, first.signed_distance), kept):
        assert torch.equal(value, copy)
    torch.testing.assert_close(again.signed_distance, first.signed_distance[:3], atol=0, rtol=0)
    fresh = BodyProximity(sphere_proximity.faces)
    fresh.update(sphere_proximity._points)
    torch.testing.assert_close(fresh.query(big, max_distance=0.2).face, sphere_proximity.query(big, max_distance=0.2).face)


def test_a_second_push_leaves_an_acute_crease_by_both_faces_and_stops_between_pressed_parts():
    """push_outside_two: off the floor (normal +z) a vertex landed inside a wall leaning over it
    (a crease under 90 degrees); the wall's plain push would put it back under the floor's
    offset plane, the two-face push puts it on both offset planes. Between two faces that face
    each other closer than twice the margin, it goes halfway and is reported trapped."""
    from hyperbones.geometry.surface import Nearest, push_outside_two

    margin = 2e-3
    floor_normal = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    pushed_to = torch.tensor([[0.0, 0.0, margin], [0.0, 0.0, margin]])  # the floor is z = 0
    wall_normal = torch.nn.functional.normalize(torch.tensor([1.0, 0.0, -0.5]), dim=0)  # leans over the floor
    ceiling_normal = torch.tensor([0.0, 0.0, -1.0])  # 1.5 mm above the floor
    normal = torch.stack([wall_normal, ceiling_normal])
    # The faces' nearest points to (0, 0, margin): the wall through x = 1 mm at that height, the ceiling above.
    point = torch.stack([torch.tensor([0.0, 0.0, margin]) + 1e-3 * torch.tensor([1.0, 0.0, 0.0]) @ wall_normal
                         * wall_normal, torch.tensor([0.0, 0.0, 1.5e-3])])
    nearest = Nearest(face=torch.tensor([7, 9]), point=point, barycentric=torch.full((2, 3), 1 / 3), normal=normal,
                      signed_distance=-((pushed_to - point) * normal).sum(1).abs())
    moved, trapped = push_outside_two(pushed_to, nearest, margin, floor_normal, pushed_to)
    plain = point[0] + margin * normal[0]
    assert float(plain[2]) < margin - 1e-4  # the wall's push alone crosses back under the floor's plane
    assert float(moved[0, 2]) == pytest.approx(margin, abs=1e-7)  # on the floor's offset plane
    assert float((moved[0] - point[0]) @ normal[0]) == pytest.approx(margin, abs=1e-7)  # and on the wall's
    assert float(moved[1, 2]) == pytest.approx(0.75e-3, abs=1e-7)  # halfway between floor and ceiling
    assert trapped.tolist() == [False, True]
