"""The runtime's contact step: garment vertices inside the body pushed out to the margin."""

import pytest
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.proximity import BodyProximity
from hyperbones.runtime.contact import BodyContact


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
    contact = BodyContact(faces, characters=1, margin=0.002)
    clear = proximity.query(outside, max_distance=0.1).signed_distance >= 0.002  # not in another body part
    assert int(clear.sum()) > 300
    (pushed,) = contact([torch.cat([inside, outside])], vertices[None])
    after = proximity.query(pushed, max_distance=0.1).signed_distance
    assert float(after[:400].min()) > 0.0015  # every one is out, at about the margin
    assert torch.equal(pushed[400:][clear], outside[clear])
    with pytest.raises(ParameterError, match="one posed body per character"):
        contact([inside, inside], torch.stack([vertices, vertices]))
