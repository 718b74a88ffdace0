"""The runtime's edge projection: stretched cloth pulled back to its rest lengths, rigid motion kept."""

import math

import pytest
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.rotations import rot_z
from hyperbones.runtime.edge_projection import EdgeProjection
from test_runtime_push_out import _grid


def _edge_strain(projection, points):
    first, second = projection.edges[:, 0], projection.edges[:, 1]
    return ((points[second] - points[first]).norm(dim=1) / projection.rest_lengths - 1).abs()


def test_a_moved_and_turned_garment_is_left_where_it_is():
    sheet, faces = _grid(10, 10, 0.02)
    projection = EdgeProjection(sheet, faces)
    moved = sheet @ rot_z(torch.tensor(0.7)).T + torch.tensor([0.3, -0.2, 1.0])
    assert torch.allclose(projection.project(moved), moved, atol=1e-6)


def test_a_stretch_spanning_the_sheet_is_largely_removed_and_the_sheet_stays_put():
    sheet, faces = _grid(16, 16, 0.02)
    projection = EdgeProjection(sheet, faces)
    stretched = sheet * torch.tensor([1.2, 1.0, 1.0])  # 20 % along x everywhere
    # A bulge along y as well, as blended bones leave it: a smooth field of ~1 cm.
    stretched[:, 1] += 0.01 * torch.sin(sheet[:, 0] * math.pi / 0.3)
    before, after = _edge_strain(projection, stretched), _edge_strain(projection, projection.project(stretched))
    assert float(before.mean()) > 0.08
    assert float(after.mean()) < 0.4 * float(before.mean())  # 0.32 measured: α keeps it near the input
    out = projection.project(stretched)
    assert float((out.mean(0) - stretched.mean(0)).norm()) < 0.01  # pulled in, not carried away
    assert out.dtype == stretched.dtype and out.shape == stretched.shape


def test_bad_settings_are_refused():
    sheet, faces = _grid(3, 3, 0.02)
    with pytest.raises(ParameterError, match="iterations"):
        EdgeProjection(sheet, faces, iterations=0)
    with pytest.raises(ParameterError, match="anchor"):
        EdgeProjection(sheet, faces, anchor=0.0)


def _stretched_sheet_with_planes(seed: int, across: float, start: int, every: int, lift: float):
    """A 14×12 sheet stretched 15 % along x, scaled by ``across`` along y and jittered by 4 mm,
    with a plane ``lift`` above every ``every``-th vertex from ``start`` (normals +z): the
    sheet, its faces, the moved positions, the planes' vertices and the ``ContactPlanes``."""
    from hyperbones.physics.contact_planes import ContactPlanes

    sheet, faces = _grid(14, 12, 0.02)
    generator = torch.Generator().manual_seed(seed)
    moved = sheet * torch.tensor([1.15, across, 1.0]) + 0.004 * torch.randn(sheet.shape, generator=generator)
    vertex = torch.arange(start, sheet.shape[0], every)
    planes = ContactPlanes(vertex, moved[vertex] + torch.tensor([0.0, 0.0, lift]),
                           torch.tensor([0.0, 0.0, 1.0]).expand(len(vertex), 3).contiguous())
    return sheet, faces, moved, vertex, planes


def test_the_dense_solver_gives_the_sparse_solvers_answer():
    """The GPU's solver (dense inverse, all torch) and the CPU's (sparse LU) agree, with contact
    planes: the CUDA path is this code on another device."""
    sheet, faces, moved, vertex, planes = _stretched_sheet_with_planes(seed=0, across=0.95, start=0, every=3,
                                                                       lift=0.002)
    sparse = EdgeProjection(sheet, faces, solver="sparse").project(moved, planes)
    dense_projection = EdgeProjection(sheet, faces, solver="dense")
    assert dense_projection.solver == "dense" and EdgeProjection(sheet, faces).solver == "sparse"  # auto on a CPU
    dense = dense_projection.project(moved, planes)
    assert float((sparse - moved).abs().max()) > 1e-3  # it did move them
    assert float((dense - sparse).abs().max()) < 1e-5
    assert float(((dense[vertex] - planes.point) * planes.normal).sum(1).min()) > -1e-6  # planes held
    with pytest.raises(ParameterError, match="solver"):
        EdgeProjection(sheet, faces, solver="cholmod")


@pytest.mark.parametrize("band", [(0.0, 0.0), (0.05, 0.02)])
def test_the_compiled_projection_gives_the_numpy_answer(band):
    """Where numba imports, the sparse solver's iterations run compiled (local step, both
    triangular solves with SuperLU's factors, the planes); the answer equals numpy's and
    SuperLU's to float32 rounding, with a band of lengths and contact planes."""
    pytest.importorskip("numba")
    sheet, faces, moved, _, planes = _stretched_sheet_with_planes(seed=1, across=0.9, start=1, every=4, lift=0.003)
    stretch, compression = band
    compiled = EdgeProjection(sheet, faces, stretch=stretch, compression=compression)
    plain = EdgeProjection(sheet, faces, stretch=stretch, compression=compression, compiled=False)
    assert compiled._compiled is not None and plain._compiled is None
    for contact in (None, planes):
        fast, slow = compiled.project(moved, contact), plain.project(moved, contact)
        assert float((slow - moved).abs().max()) > 1e-3  # it did move them
        assert float((fast - slow).abs().max()) < 1e-6


def test_planes_one_per_vertex_are_applied_as_several_per_vertex_are():
    """The in-place path for one plane a vertex gives the summed path's numbers, bit for bit."""
    import numpy as np

    from hyperbones.runtime.edge_projection import _onto_planes

    rng = np.random.default_rng(5)
    x = rng.normal(size=(200, 3)).astype(np.float32)
    vertex = np.sort(rng.choice(200, 60, replace=False))
    point = rng.normal(size=(60, 3)).astype(np.float32)
    normal = rng.normal(size=(60, 3)).astype(np.float32)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    one_each = _onto_planes(x, vertex, point, normal)
    # The same planes plus one that never pushes, out of order: the summing path.
    shuffled = np.concatenate([vertex[::-1], vertex[:1]])
    summed = _onto_planes(x, shuffled, np.concatenate([point[::-1], x[vertex[:1]] - normal[:1]]),
                          np.concatenate([normal[::-1], normal[:1]]))
    assert (one_each != x).any(axis=1).sum() > 10  # some vertices were behind their plane
    assert np.array_equal(one_each, summed)
    try:  # the compiled pass, where numba imports: the same numbers, several planes a vertex too
        from hyperbones.runtime.projection_local import onto_planes
    except ImportError:
        return
    for planes in ((vertex, point, normal), (shuffled, np.concatenate([point[::-1], x[vertex[:1]] - normal[:1]]),
                                             np.concatenate([normal[::-1], normal[:1]]))):
        compiled = onto_planes(x.copy(), *planes, np.empty((len(planes[0]), 3), np.float32))
        assert np.abs(compiled - one_each).max() < 1e-6
