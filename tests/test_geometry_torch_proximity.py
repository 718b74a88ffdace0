"""TorchProximity, the plain-torch nearest-face search: Warp's answers on the Anny body, exact
answers on small meshes, batches and chunks, and no Warp, Numba or Anny needed."""

import json
import subprocess
import sys

import pytest
import torch

from hyperbones.geometry.proximity import BodyProximity
from hyperbones.geometry.surface import closest_points_on_faces, surface_points
from hyperbones.geometry.torch_proximity import TorchProximity
from test_geometry_proximity import icosphere

F64 = torch.float64


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """The search runs many small tensor operations; on the shared two-core machine a second
    torch thread mostly waits for a busy core, so these tests run on one."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def skin_points(vertices: torch.Tensor, faces: torch.Tensor, count: int, seed: int) -> torch.Tensor:
    """(count,3) points near the skin, 2 cm inside to 5 cm outside along the vertex normals and
    jittered by a few mm, and a tenth of them 1.3–2 m from the body's middle (far from it)."""
    generator = torch.Generator().manual_seed(seed)
    corners = vertices[faces]
    area_normals = torch.linalg.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], dim=-1)
    normals = torch.zeros_like(vertices).index_add_(0, faces.reshape(-1), area_normals.repeat_interleave(3, dim=0))
    normals = torch.nn.functional.normalize(normals, dim=-1)
    near = count - count // 10
    index = torch.randint(0, vertices.shape[0], (near,), generator=generator)
    offset = -0.02 + 0.07 * torch.rand(near, 1, generator=generator)
    points = vertices[index] + offset * normals[index] + 0.004 * torch.randn(near, 3, generator=generator)
    directions = torch.nn.functional.normalize(torch.randn(count // 10, 3, generator=generator), dim=-1)
    far = vertices.mean(dim=0) + directions * (1.3 + 0.7 * torch.rand(count // 10, 1, generator=generator))
    return torch.cat([points, far])


@pytest.fixture(scope="module")
def frames(body):
    """Five posed frames of the walk (Vb,3) each, float32."""
    from hyperbones.motion.load import load_motion

    motion = load_motion("walk", body)
    posed = body.pose(motion.joint_rotations[:5], motion.root_translation[:5])
    return posed.vertices.detach().float()


@pytest.fixture(scope="module", params=["rest", "posed"])
def pair(request, body, frames):
    """(vertices, TorchProximity, BodyProximity), both fitted to the rest body or to walk frame 4."""
    vertices = body.rest_vertices.float() if request.param == "rest" else frames[4]
    torch_proximity, warp_proximity = TorchProximity(body.faces), BodyProximity(body.faces)
    torch_proximity.update(vertices)
    warp_proximity.update(vertices)
    return vertices, torch_proximity, warp_proximity


@pytest.mark.parametrize("max_distance", [0.1, 0.04])
def test_matches_warp_on_the_anny_body(body, pair, max_distance):
    vertices, torch_proximity, warp_proximity = pair
    points = skin_points(vertices, body.faces, 3000, seed=1)
    ours, warp = torch_proximity.query(points, max_distance), warp_proximity.query(points, max_distance)
    assert torch.equal(ours.found, warp.found)
    found = ours.found
    assert 0.5 * len(points) < found.sum() < len(points) - 250  # both sides of the cut-off are exercised
    assert float((ours.signed_distance[found] - warp.signed_distance[found]).abs().max()) <= 1e-5
    clear = found & (warp.signed_distance.abs() > 1e-4)
    assert torch.equal(ours.signed_distance[clear] < 0, warp.signed_distance[clear] < 0)
    assert bool((ours.signed_distance[found] < 0).any())  # points inside the body too
    # Faces differ where the nearest point lies on both (a shared edge or corner: our closest
    # point is on Warp's face too) or, rarely, where two skin points tie in float32.
    on_warp_face = closest_points_on_faces(ours.point[found].double(), vertices.double(), body.faces, warp.face[found])
    elsewhere = (on_warp_face - ours.point[found].double()).norm(dim=-1) > 1e-5
    assert int(elsewhere.sum()) <= 0.002 * int(found.sum())
    assert bool(((ours.signed_distance - warp.signed_distance)[found][elsewhere].abs() <= 1e-6).all())
    skin = surface_points(vertices, body.faces, ours.face[found], ours.barycentric[found])
    assert float((skin - ours.point[found]).norm(dim=-1).max()) <= 1e-6
    same = found & (ours.face == warp.face)
    assert same.float().sum() > 0.5 * found.sum()
    assert torch.allclose(ours.normal[same], warp.normal[same], atol=1e-5)
    assert torch.allclose(ours.barycentric[same], warp.barycentric[same], atol=1e-4)
    missed = ~found
    assert bool((ours.face[missed] == -1).all()) and torch.equal(ours.point[missed], points[missed])
    assert bool((ours.normal[missed] == 0).all()) and bool((ours.barycentric[missed] == 0).all())
    assert bool(torch.isinf(ours.signed_distance[missed]).all())


def test_a_batch_of_bodies_answers_like_each_body_alone_and_chunks_change_nothing(body, frames):
    points = torch.stack([skin_points(frame, body.faces, 400, seed=i) for i, frame in enumerate(frames)])
    batched = TorchProximity(body.faces)
    batched.update(frames)
    assert torch.equal(batched.faces, body.faces)
    together = batched.query(points.reshape(5, 20, 20, 3), max_distance=0.1)
    assert together.face.shape == (5, 20, 20) and together.point.shape == (5, 20, 20, 3)
    alone = TorchProximity(body.faces, memory_budget=2**18)  # chunks of a few dozen points
    for i, frame in enumerate(frames):  # refits; the hierarchy comes from frame 0 in both
        alone.update(frame)
        answer = alone.query(points[i], max_distance=0.1)
        assert torch.equal(answer.face, together.face[i].reshape(-1))
        assert torch.equal(answer.signed_distance, together.signed_distance[i].reshape(-1))
        assert torch.equal(answer.point, together.point[i].reshape(-1, 3))
    with pytest.raises(ValueError):
        batched.query(points[:2])
    with pytest.raises(RuntimeError):
        TorchProximity(body.faces).query(points[0])


def test_icosphere_faces_and_distances_are_exact():
    vertices, faces = icosphere(3)  # 1280 faces, convex and outward wound
    proximity = TorchProximity(faces)
    proximity.update(vertices)
    corners = vertices[faces]
    centroid = corners.mean(dim=1)
    normal = torch.nn.functional.normalize(torch.linalg.cross(corners[:, 1] - corners[:, 0],
                                                              corners[:, 2] - corners[:, 0], dim=-1), dim=-1)
    # On a convex surface, a point off a face's centroid along its normal (outward by any
    # amount, inward by less than the gap to the neighbouring planes) has that face nearest.
    heights = torch.tensor([0.08, 0.01, 1e-3, -1e-3, -3e-4], dtype=F64)
    chosen = torch.arange(0, faces.shape[0], 7)
    points = (centroid[chosen, None] + heights[:, None] * normal[chosen, None]).reshape(-1, 3)
    nearest = proximity.query(points, max_distance=0.1)
    assert nearest.signed_distance.dtype == F64
    assert torch.equal(nearest.face, chosen.repeat_interleave(len(heights)))
    assert torch.allclose(nearest.signed_distance, heights.repeat(len(chosen)), atol=1e-6)
    assert torch.allclose(nearest.point, centroid[chosen].repeat_interleave(len(heights), 0), atol=1e-6)
    assert torch.allclose(nearest.barycentric, torch.full_like(nearest.barycentric, 1 / 3), atol=1e-5)
    assert torch.allclose(nearest.normal, normal[chosen].repeat_interleave(len(heights), 0), atol=1e-6)
    # Anywhere: the distance is the least over all faces, the sign says inside the unit sphere.
    generator = torch.Generator().manual_seed(0)
    directions = torch.nn.functional.normalize(torch.randn(600, 3, dtype=F64, generator=generator), dim=-1)
    points = directions * (0.5 + torch.rand(600, 1, dtype=F64, generator=generator))
    nearest = proximity.query(points, max_distance=1.0)
    brute = torch.stack([(closest_points_on_faces(points, vertices, faces, torch.full((600,), f)) - points).norm(dim=-1)
                         for f in range(faces.shape[0])]).amin(dim=0)
    assert torch.allclose(nearest.signed_distance.abs(), brute, atol=1e-6)
    radius = points.norm(dim=-1)
    clear = (radius - 1).abs() > 0.01  # farther from the unit sphere than its facets sag
    assert torch.equal(nearest.signed_distance[clear] < 0, radius[clear] < 1)
    far = proximity.query(torch.tensor([[0.0, 0.0, 1.5], [0.0, 0.0, 1.05]]), max_distance=0.1)
    assert far.face[0] == -1 and far.face[1] >= 0 and far.signed_distance[0] == float("inf")


def fanned_tetrahedron(slivers: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A sharp tetrahedron v=0, a=x, b=y, c=(0.1,0.1,0.6), outward wound, whose face vba is
    cut into a fan of thin triangles at v (and face abc along ab to match)."""
    along = torch.linspace(0, 1, slivers + 1, dtype=F64)[:, None]
    edge = torch.tensor([1.0, 0, 0], dtype=F64) * (1 - along) + torch.tensor([0, 1.0, 0], dtype=F64) * along
    vertices = torch.cat([torch.zeros(1, 3, dtype=F64), torch.tensor([[0.1, 0.1, 0.6]], dtype=F64), edge])
    faces = [[0, i + 3, i + 2] for i in range(slivers)] + [[1, i + 2, i + 3] for i in range(slivers)]
    return vertices, torch.tensor(faces + [[0, 2, 1], [0, 1, slivers + 2]])


def test_signs_follow_warps_angle_weighted_pseudo_normals():
    # Near a vertex where one side is a fan of slivers, only weighting each face by its angle
    # there gives the right side; with equal weights the fan's plane outvotes the others.
    slivers = 30
    vertices, faces = fanned_tetrahedron(slivers)
    generator = torch.Generator().manual_seed(0)
    directions = torch.nn.functional.normalize(torch.randn(3000, 3, dtype=F64, generator=generator), dim=-1)
    points = directions * (0.02 + 0.1 * torch.rand(3000, 1, dtype=F64, generator=generator))
    v, c, a, b = 0, 1, 2, slivers + 2
    corners = vertices[torch.tensor([[v, b, a], [v, a, c], [v, c, b], [c, a, b]])]  # the four planes, wound outward
    normals = torch.linalg.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], dim=-1)
    inside = (torch.einsum("pk,fk->pf", points, normals) - (corners[:, 0] * normals).sum(-1) < 0).all(dim=1)
    proximity = TorchProximity(faces)
    proximity.update(vertices)
    signed = proximity.query(points).signed_distance
    clear = signed.abs() > 1e-3
    assert 200 < int(inside.sum()) and torch.equal(signed[clear] < 0, inside[clear])
    warp = BodyProximity(faces, sign="normal")
    warp.update(vertices)
    clear = signed.abs() > 1e-4
    assert torch.equal(signed[clear] < 0, warp.query(points).signed_distance[clear] < 0)
    # A bumpy sphere: sharp ridges and pits everywhere; the faces tied within Warp's ε of
    # the nearest all count (the nearest face's normal alone gets ~1% of these wrong).
    vertices, faces = icosphere(2)
    vertices = vertices * (0.7 + 0.6 * torch.rand(vertices.shape[0], 1, dtype=F64, generator=generator))
    index = torch.randint(0, vertices.shape[0], (4000,), generator=generator)
    points = vertices[index] + 0.03 * torch.randn(4000, 3, dtype=F64, generator=generator)
    proximity = TorchProximity(faces)
    proximity.update(vertices)
    warp = BodyProximity(faces, sign="normal")
    warp.update(vertices)
    ours, theirs = proximity.query(points).signed_distance, warp.query(points).signed_distance
    clear = theirs.abs() > 1e-4
    assert int(((ours < 0) != (theirs < 0))[clear].sum()) <= 4  # Warp's tie set depends on its BVH order


def test_imports_and_answers_without_warp_numba_or_anny():
    script = """
import json, sys
for name in ("warp", "numba", "anny"):
    sys.modules[name] = None  # any import of them now fails
import torch
from hyperbones.geometry.torch_proximity import TorchProximity
tetrahedron = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
proximity = TorchProximity(torch.tensor([[0, 2, 1], [0, 3, 2], [0, 1, 3], [1, 2, 3]]))
proximity.update(tetrahedron)
nearest = proximity.query(torch.tensor([[0.2, 0.2, -0.5], [0.1, 0.2, 0.3], [3.0, 3, 3]]), max_distance=1.0)
loaded = [name for name, module in sys.modules.items() if name.split(".")[0] in ("warp", "numba", "anny") and module]
print(json.dumps({"face": nearest.face.tolist(), "distance": nearest.signed_distance.tolist(), "loaded": loaded}))
"""
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    answer = json.loads(result.stdout.strip().splitlines()[-1])
    assert answer["face"] == [0, 1, -1] and answer["loaded"] == []
    assert answer["distance"][0] == pytest.approx(0.5) and answer["distance"][1] == pytest.approx(-0.1)
    assert answer["distance"][2] == float("inf")
