"""The body's skinning rig on its own: it poses the mesh as ``Body.pose`` does, and a bad file is named."""

import pytest
import torch

from hyperbones.body.anny_body import body_for
from hyperbones.body.rig import BodyRig
from hyperbones.body.shape import BodyShape
from hyperbones.errors import InputFileError
from hyperbones.motion.load import load_motion


def test_a_saved_rig_poses_the_body_as_the_body_does(tmp_path):
    body = body_for(BodyShape())
    motion = load_motion("walk", body).slice(0, 6)
    path = BodyRig.of(body).save(tmp_path / "body.rig.pt")
    rig = BodyRig.load(path)
    posed = rig.pose(motion.joint_rotations, motion.root_translation)
    expected = body.pose(motion.joint_rotations, motion.root_translation).vertices
    assert posed.shape == expected.shape
    assert float((posed - expected).abs().max()) < 1e-6
    assert float((posed[5] - posed[0]).norm(dim=1).max()) > 0.01  # the walk moves it
    assert torch.equal(rig.faces, body.faces.cpu())


def test_a_damaged_rig_is_named(tmp_path):
    body = body_for(BodyShape())
    rig = BodyRig.of(body)
    rig.faces = rig.faces.clone()
    rig.faces[0, 0] = rig.rest_vertices.shape[0] + 5
    path = rig.save(tmp_path / "bad.rig.pt")
    with pytest.raises(InputFileError, match="bad.rig.pt.*face indices"):
        BodyRig.load(path)
    (tmp_path / "junk.pt").write_text("not a rig")
    with pytest.raises(InputFileError, match="junk.pt"):
        BodyRig.load(tmp_path / "junk.pt")
