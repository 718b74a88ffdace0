"""Evaluation metrics, each with its convention named (REFERENCE.md, "Metrics").

All take whole rollouts: garment positions (T,V,3) in metres (a single (V,3) frame also
works). They return plain tensors; nothing here needs gradients.
"""

from __future__ import annotations

import torch

from hyperbones.physics.cloth import ClothRest, triangle_areas
from hyperbones.physics.energies import (
    GRAVITY,
    bending_energy,
    gravity_energy,
    inertia_energy,
    stretching_energy,
)
from hyperbones.physics.material import Material

HOOD_COLLISION_THRESHOLD = 1e-3
"""HOOD counts a vertex as colliding when its signed distance is below 1 mm."""
DETACH_MARGIN = 0.10
"""``detached_pct`` counts a vertex as come off when it is this much (m) farther from the skin than in the drape."""


def edge_error_pct(x: torch.Tensor, rest: ClothRest) -> torch.Tensor:
    """GAPS edge error ε_e: mean over frames and all undirected edges of |l − l⁰| / l⁰, × 100.

    x: (T,V,3) (or (V,3)); rest lengths l⁰ from the canonical 3D template. Returns a 0-d tensor (%).
    Zero-length rest edges are left out (their relative error is undefined).
    """
    edges = rest.edges
    lengths = (x[..., edges[:, 1], :] - x[..., edges[:, 0], :]).norm(dim=-1)
    rest_lengths = rest.edge_lengths.to(x)
    valid = rest_lengths > 0
    relative = (lengths[..., valid] - rest_lengths[valid]).abs() / rest_lengths[valid]
    return 100.0 * relative.mean()


def area_error_pct(x: torch.Tensor, rest: ClothRest) -> torch.Tensor:
    """GAPS area error ε_a: mean over frames and faces of |A_f − A_f⁰| / A_f⁰, × 100.

    x: (T,V,3) (or (V,3)); A_f⁰ from the canonical 3D template (not UVs). Returns a 0-d tensor (%).
    Zero-area rest faces are left out.
    """
    rest_areas = triangle_areas(rest.rest_vertices, rest.faces).to(x)
    valid = rest_areas > 0
    areas = triangle_areas(x, rest.faces[valid])
    return 100.0 * ((areas - rest_areas[valid]).abs() / rest_areas[valid]).mean()


def collision_pct(signed_distances: torch.Tensor, threshold: float = 0.0) -> torch.Tensor:
    """Collision ε_c: % of garment vertex-frames with signed body distance d < threshold.

    signed_distances: (T,V) (any shape), negative inside the body (``Nearest.signed_distance``;
    +inf for vertices with no body face in range counts as outside). threshold 0 is the
    paper's "inside the body"; ``HOOD_COLLISION_THRESHOLD`` (1 mm) is HOOD's variant.
    Returns a 0-d tensor (%).
    """
    return 100.0 * (signed_distances < threshold).to(torch.float64).mean()


def per_frame_energies(
    x: torch.Tensor,
    rest: ClothRest,
    dt: float = 1.0 / 30.0,
    material: Material | None = None,
    g: float = GRAVITY,
) -> dict[str, torch.Tensor]:
    """HOOD's per-frame energy protocol: (T,V,3) -> {name: (T−2,)} in joules.

    For each frame t ≥ 2, stretching, bending and gravity of x[t], and inertia from
    x[t−2], x[t−1], x[t]. Evaluated with ``material`` (HOOD's defaults when None, as the
    protocol prescribes, whatever material ``rest`` was built with; masses follow its
    density). Gravity is absolute height energy: its zero is z = 0, so the caller fixes
    the origin (body root at frame 0) before comparing methods.
    """
    if x.dim() != 3 or x.shape[0] < 3:
        raise ValueError(f"per_frame_energies needs (T,V,3) with T >= 3, got {tuple(x.shape)}")
    rest = rest.with_material(material or Material())
    with torch.no_grad():
        current = x[2:]
        return {
            "stretching": stretching_energy(current, rest),
            "bending": bending_energy(current, rest),
            "inertia": inertia_energy(current, x[1:-1], x[:-2], rest, dt),
            "gravity": gravity_energy(current, rest, g),
        }


def mean_energies(
    x: torch.Tensor,
    rest: ClothRest,
    dt: float = 1.0 / 30.0,
    material: Material | None = None,
    g: float = GRAVITY,
) -> dict[str, float]:
    """``per_frame_energies`` averaged over frames: (T,V,3) -> {name: joules}.

    Average these per sequence, then over sequences (REFERENCE.md, "Per-frame energies").
    """
    return {name: float(values.mean()) for name, values in per_frame_energies(x, rest, dt, material, g).items()}


def detached_pct(distances: torch.Tensor, drape_distances: torch.Tensor, margin: float = DETACH_MARGIN) -> float:
    """(T,V) signed distances to the posed body, (V,) the same vertices' in the drape -> % of
    vertex-frames farther from the skin than in the drape by more than ``margin`` (m).

    A garment that slides off an arm or hangs from one shoulder stays near its rest lengths and
    outside the body, so ε_e, ε_a and ε_c do not see it; this does. A vertex beyond the search
    range (infinite distance) counts as come off.
    """
    return float(100.0 * ((distances - drape_distances.to(distances)) > margin).float().mean())


def enclosed_area(loop_points: torch.Tensor) -> torch.Tensor:
    """(...,L,3) an ordered closed loop -> (...) the area it encloses seen from above (m², the
    shoelace formula on x, y; lobes of a loop that crosses itself partly cancel).

    For a hem: a skirt spanning between the legs encloses far more than one wrapped around a
    leg like a trouser leg, which its convex hull would not tell apart.
    """
    x, y = loop_points[..., 0], loop_points[..., 1]
    return 0.5 * (x * y.roll(-1, -1) - x.roll(-1, -1) * y).sum(-1).abs()
