"""Procedural templates: resolution, UV atlas, openings, waistbands, fit to the body."""

import numpy as np
import pytest
import torch

from hyperbones.body import BodyShape, body_for
from hyperbones.errors import ParameterError
from hyperbones.garment import TEMPLATES, make_template
from hyperbones.garment.surface import weld

# Open rims each template must have: neck, hem, sleeves, waist, ankles.
OPENINGS = {"tshirt": 4, "tshirt-open": 3, "pants": 3, "long-skirt": 2, "dress": 4, "tight-dress": 4}
PINNED = {"pants", "long-skirt", "dress", "tight-dress"}
RESOLUTION = 1500


def boundary_loops(faces: torch.Tensor) -> int:
    """Number of open rims (connected components of the boundary edges)."""
    import scipy.sparse
    import scipy.sparse.csgraph

    edges = torch.sort(torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), dim=1).values
    unique, counts = torch.unique(edges, dim=0, return_counts=True)
    rim = unique[counts == 1].numpy()
    n = int(faces.max()) + 1
    graph = scipy.sparse.coo_matrix((np.ones(len(rim)), (rim[:, 0], rim[:, 1])), shape=(n, n))
    _, labels = scipy.sparse.csgraph.connected_components(graph, directed=False)
    return len(np.unique(labels[np.unique(rim)]))


@pytest.fixture(scope="module")
def templates(body):
    return {name: make_template(name, body, RESOLUTION) for name in TEMPLATES}


@pytest.mark.parametrize("name", sorted(OPENINGS))
def test_template_mesh(templates, body, name):
    garment = templates[name]
    assert abs(garment.num_vertices - RESOLUTION) < 0.15 * RESOLUTION
    assert boundary_loops(garment.faces) == OPENINGS[name]
    assert 0 <= float(garment.uvs.min()) and float(garment.uvs.max()) <= 1
    # Faces cover the atlas: at most one in a thousand may get no UV area (xatlas can
    # flatten a tiny rim triangle to a line).
    uv = garment.uvs[garment.face_uvs]
    uv_area = (uv[:, 1, 0] - uv[:, 0, 0]) * (uv[:, 2, 1] - uv[:, 0, 1]) - (uv[:, 2, 0] - uv[:, 0, 0]) * (uv[:, 1, 1] - uv[:, 0, 1])
    assert float((uv_area.abs() > 0).float().mean()) > 0.999
    # Seams: some vertices carry several UVs, and the welded mesh is one piece.
    assert len(garment.uvs) > garment.num_vertices
    # It covers the body where it should.
    z = garment.vertices[:, 2]
    assert float(z.max()) < float(body.rest_vertices[:, 2].max()) - 0.15  # below the head
    if name in PINNED:
        pinned_z = z[garment.pinned]
        assert len(garment.pinned) > 10 and float(pinned_z.max() - pinned_z.min()) < 0.06
    else:
        assert len(garment.pinned) == 0


def test_template_follows_body_shape():
    slim = body_for(BodyShape(weight=0.0))
    heavy = body_for(BodyShape(weight=1.0))
    from hyperbones.garment.surface import surface_area

    areas = [surface_area(g.vertices.double().numpy(), g.faces.numpy())
             for g in (make_template("pants", b, 1200) for b in (slim, heavy))]
    assert areas[1] > 1.08 * areas[0]


def test_resolution_scales(body):
    small = make_template("tight-dress", body, 1200)
    large = make_template("tight-dress", body, 4000)
    assert large.num_vertices > 2.5 * small.num_vertices


def test_bad_requests(body):
    with pytest.raises(ParameterError, match="unknown garment template"):
        make_template("cape", body)
    with pytest.raises(ParameterError, match="--vertices"):
        make_template("dress", body, 100)


def test_weld_merges_duplicates():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [3, 2, 0]])
    welded, new_faces = weld(vertices, faces)
    assert len(welded) == 3 and new_faces.max() == 2
