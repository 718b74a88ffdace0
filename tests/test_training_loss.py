"""Module A's loss (``runtime_terms``), each term against its value worked out by hand on a
few vertices (float64, so the comparison can be tight)."""

import math

import pytest
import torch

from hyperbones.geometry.surface import Nearest
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.energies import COLLISION_EPSILON
from hyperbones.physics.material import Material
from hyperbones.training.config import JointConfig
from hyperbones.training.loss import edge_length_error, runtime_terms

# Round numbers, so the energies below can be written out: E_stretch = A h (μ tr G² + ½λ (tr G)²),
# E_bend = k_b l² / (4 (A1 + A2)) · θ² / 2.
UNIT_CLOTH = Material(lame_mu=1.0, lame_lambda=2.0, thickness=1.0, density=1.0, bending=1.0)

# The body: one triangle in the plane z = 0, wound so that its normal is +z.
BODY = torch.tensor([[-1.0, -1.0, 0.0], [3.0, -1.0, 0.0], [-1.0, 3.0, 0.0]], dtype=torch.float64)
BODY_FACES = torch.tensor([[0, 1, 2]])

# The garment: a unit square of two triangles (edges 0-1, 1-2, 0-2, 2-3, 0-3: vertices 0 and 2
# have three neighbours, 1 and 3 two).
SQUARE = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
SQUARE_FACES = torch.tensor([[0, 1, 2], [0, 2, 3]])


def _nearest(faces: list[int]) -> Nearest:
    """Nearest body faces as ``BodyProximity.query`` gives them (only ``face`` is read by the loss)."""
    face = torch.tensor(faces)
    count = len(faces)
    return Nearest(face, torch.zeros(count, 3), torch.zeros(count, 3), torch.zeros(count, 3), torch.zeros(count))


def _terms(positions, target, faces, nearest, collision_weight=1.0, **config):
    rest = ClothRest.from_mesh(SQUARE if positions.shape[0] == 4 else positions.detach(), faces, UNIT_CLOTH)
    return runtime_terms(positions, target, rest.edges, rest, nearest, BODY, BODY_FACES, collision_weight,
                         JointConfig(**config))


def test_l3d_terms_by_hand():
    # A's square: vertex 1 is 1 cm above the body, vertex 2 is 2 mm inside it, vertex 3 is
    # 1 mm above it but finds no body face (it must not count).
    positions = SQUARE.clone()
    positions[1, 2], positions[2, 2], positions[3, 2] = 0.01, -0.002, 0.001
    # C's square differs from A's at vertex 1 only, by 1 cm along z.
    error = torch.zeros(4, 3, dtype=torch.float64)
    error[1, 2] = 0.01
    target = positions - error
    terms = _terms(positions.requires_grad_(), target.requires_grad_(), SQUARE_FACES, _nearest([0, 0, 0, -1]),
                   position_scale=1e4, laplacian_weight=0.5, interpenetration_weight=2.0,
                   interpenetration_epsilon=0.003, physics_on_runtime=False)
    assert set(terms) == {"a_mse", "a_laplacian", "a_interpenetration"}
    value = {name: term.item() for name, term in terms.items()}
    # MSE: (1 cm)² on one of four vertices, in cm².
    assert value["a_mse"] == pytest.approx(1.0 / 4, rel=1e-9)
    # The error's Laplacian (z): vertex 0: 0 − (0.01 + 0 + 0)/3; vertex 1: 0.01 − (0 + 0)/2;
    # vertex 2: 0 − (0 + 0.01 + 0)/3; vertex 3: 0 − (0 + 0)/2. Mean of the squares, in cm², × λ_lap.
    laplacian_cm = [-1 / 3, 1.0, -1 / 3, 0.0]
    assert value["a_laplacian"] == pytest.approx(0.5 * sum(x * x for x in laplacian_cm) / 4, rel=1e-9)
    # max(0, ε − d) with d the height above the body plane: 3 mm, 0, 5 mm, and 0 (no face);
    # mean of the squares (m²) × position_scale × λ_interp.
    assert value["a_interpenetration"] == pytest.approx(2.0 * 1e4 * (0.003**2 + 0.005**2) / 4, rel=1e-9)
    # The target is C's state: no gradient reaches it. A's gradient of the MSE is
    # 2 · error · scale / V.
    terms["a_mse"].backward()
    assert target.grad is None
    assert torch.allclose(positions.grad, 2 * error * 1e4 / 4, rtol=0, atol=1e-9)


def test_position_scale_and_a_shifted_garment():
    """A garment off C's by the same 2 cm everywhere: MSE (2 cm)² (4e-4 m² at scale 1),
    no Laplacian (each vertex's error equals its neighbours' mean)."""
    target = SQUARE + 1.0  # far above the body: no interpenetration
    positions = target + torch.tensor([0.0, 0.02, 0.0], dtype=torch.float64)
    for scale, expected in ((1.0, 4e-4), (1e4, 4.0)):
        terms = _terms(positions, target, SQUARE_FACES, _nearest([0, 0, 0, 0]), position_scale=scale,
                       physics_on_runtime=False)
        assert float(terms["a_mse"]) == pytest.approx(expected, rel=1e-9)
        assert float(terms["a_laplacian"]) == pytest.approx(0.0, abs=1e-20)
        assert float(terms["a_interpenetration"]) == 0.0


def test_edge_length_term_by_hand():
    """L_edge: frame 0 has vertex 1 of A 1 cm further along x than C's (edge 0-1 1 cm longer,
    edge 1-2 longer by sqrt(1.0001) − 1); frame 1 is C's square turned and moved, so its edges
    match C's exactly while its MSE is large. The mean over frames of each frame's edge mean."""
    turn = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    target = torch.cat([SQUARE, SQUARE + 5.0])
    positions = torch.cat([SQUARE, SQUARE @ turn.T + 7.0])
    positions[1, 0] += 0.01
    edges = torch.tensor([[0, 1], [1, 2], [0, 2], [2, 3], [0, 3]])
    edges = torch.cat([edges, edges + 4])
    expected = (0.01**2 + (math.sqrt(1.0001) - 1) ** 2) / 5 / 2
    assert float(edge_length_error(positions, target, edges, [4, 4])) == pytest.approx(expected, rel=1e-9)
    # Frame 1 alone (its edges renumbered), moved rigidly, has no error.
    assert float(edge_length_error(positions[4:], target[4:], edges[5:] - 4, [4])) == pytest.approx(0.0, abs=1e-24)
    # Frames of different sizes weigh alike: frame 0 (five edges) beside a triangle (three edges)
    # whose edge 0-1 is 2 cm longer than C's.
    triangle = SQUARE[:3].clone()
    stretched = triangle.clone()
    stretched[1, 0] += 0.02
    mixed = edge_length_error(torch.cat([positions[:4], stretched]), torch.cat([target[:4], triangle]),
                              torch.cat([edges[:5], torch.tensor([[4, 5], [5, 6], [4, 6]])]), [4, 3])
    triangle_error = (0.02**2 + (math.sqrt(1 + 0.02**2) - 1) ** 2) / 3
    assert float(mixed) == pytest.approx((2 * expected + triangle_error) / 2, rel=1e-9)
    # In runtime_terms: off by default; λ_edge × scale × the one frame's edge mean.
    frame = positions[:4].clone().requires_grad_()
    off = _terms(frame, SQUARE, SQUARE_FACES, _nearest([0, 0, 0, 0]), physics_on_runtime=False)
    assert "a_edge_length" not in off
    on = _terms(frame, SQUARE, SQUARE_FACES, _nearest([0, 0, 0, 0]), physics_on_runtime=False,
                edge_weight=3.0, position_scale=1e4)
    assert on["a_edge_length"].item() == pytest.approx(3.0 * 1e4 * 2 * expected, rel=1e-9)
    on["a_edge_length"].backward()
    assert frame.grad[1, 0] > 0 and frame.grad[3].abs().max() == 0  # only the lengthened edges pull


def test_physics_terms_on_a_stretched_triangle():
    # Rest: a right triangle of area ½. A stretches it by s = 1.1 along x: FᵀF has
    # eigenvalues s² and 1, so G has ½(s² − 1) and 0, and
    # E = ½ · 1 · (μ + ½λ) · (½(s² − 1))² = ½ · 2 · 0.105².
    rest_vertices = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2]])
    rest = ClothRest.from_mesh(rest_vertices, faces, UNIT_CLOTH)
    stretched = rest_vertices * torch.tensor([1.1, 1.0, 1.0], dtype=torch.float64)
    terms = runtime_terms(stretched, stretched, rest.edges, rest, _nearest([0, 0, 0]), BODY, BODY_FACES, 1.0,
                          JointConfig())
    assert float(terms["a_stretching"]) == pytest.approx(0.5 * 2.0 * 0.105**2, rel=1e-9)
    assert float(terms["a_bending"]) == 0.0  # one triangle: no hinge
    assert float(terms["a_collision"]) == 0.0  # 1 m above the body


def test_physics_terms_on_a_folded_pair():
    # Two triangles on the edge 0-1 (length 1, rest areas ½ each), the second folded up by
    # φ about it: rigid, so no stretching; bending k_b l² / (4 (½ + ½)) · φ² / 2 = φ² / 8.
    phi = 0.3
    rest_vertices = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [0.5, -1.0, 0.0]],
                                 dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2], [1, 0, 3]])
    rest = ClothRest.from_mesh(rest_vertices, faces, UNIT_CLOTH)
    folded = rest_vertices.clone()
    folded[3] = torch.tensor([0.5, -math.cos(phi), math.sin(phi)], dtype=torch.float64)
    lifted = folded + torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64)  # clear of the body
    terms = runtime_terms(lifted, lifted, rest.edges, rest, _nearest([0, 0, 0, 0]), BODY, BODY_FACES, 1.0,
                          JointConfig())
    assert float(terms["a_stretching"]) == pytest.approx(0.0, abs=1e-20)
    assert float(terms["a_bending"]) == pytest.approx(phi**2 / 8, rel=1e-9)
    assert float(terms["a_collision"]) == 0.0


def test_collision_term_by_hand():
    # Heights above the body plane 0, 1 cm, −2 mm and (no face) −1 mm: HOOD's
    # w Σ max(0, ε − d)³ with ε = 2 mm counts (2 mm)³ and (4 mm)³.
    positions = SQUARE.clone()
    positions[1, 2], positions[2, 2], positions[3, 2] = 0.01, -0.002, -0.001
    terms = _terms(positions, positions, SQUARE_FACES, _nearest([0, 0, 0, -1]), collision_weight=1e5)
    assert COLLISION_EPSILON == 0.002
    assert float(terms["a_collision"]) == pytest.approx(1e5 * (0.002**3 + 0.004**3), rel=1e-9)
