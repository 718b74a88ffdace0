"""Canonical drape and shape transfer."""

import torch

from hyperbones.body import BodyShape, body_for
from hyperbones.garment import make_template
from hyperbones.garment.drape import drape, transfer
from hyperbones.geometry.proximity import BodyProximity


def _signed_distances(garment, body):
    proximity = BodyProximity(body.faces)
    proximity.update(body.rest_vertices)
    return proximity.query(garment.vertices, max_distance=0.5).signed_distance


def test_drape_settles_without_penetration(body):
    garment = make_template("long-skirt", body, 1500)
    draped, report = drape(garment, body)
    assert report.energy_after < report.energy_before
    assert report.penetrating_after == 0 and (_signed_distances(draped, body) >= 0).all()
    assert report.edge_error_pct < 3.0
    # Gravity pulls the free hem down; the pinned waistband stays.
    assert float(draped.vertices[:, 2].min()) < float(garment.vertices[:, 2].min()) - 0.005
    assert torch.equal(draped.vertices[garment.pinned], garment.vertices[garment.pinned])


def test_transfer_to_another_shape_then_drape(body):
    garment, _ = drape(make_template("tshirt", body, 1500), body, max_rounds=3)
    heavy = body_for(BodyShape(weight=1.0, muscle=1.0))
    moved = transfer(garment, body, heavy)
    assert float(moved.vertices[:, 0].abs().max()) > float(garment.vertices[:, 0].abs().max())
    from hyperbones.physics.cloth import ClothRest

    rest = ClothRest.from_mesh(garment.vertices.double(), garment.faces, garment.material)
    draped, report = drape(moved, heavy, rest=rest, max_rounds=3)
    assert (_signed_distances(draped, heavy) >= 0).all()
    assert report.penetrating_after == 0
