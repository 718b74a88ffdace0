"""Write a posed motion to ``.npz`` (the motion export contract)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hyperbones.body.anny_body import Body
from hyperbones.body.skeleton import JOINT_NAMES, JOINT_PARENTS
from hyperbones.errors import ParameterError
from hyperbones.io_utils import atomic_path
from hyperbones.motion.motion import Motion


def save_motion_npz(motion: Motion, body: Body, path: str | Path) -> Path:
    """Pose ``body`` with ``motion`` and write the skeleton to ``path`` (atomically).

    Keys:
        joint_names: (31,) str, the cmu_mb labels.
        joint_parents: (31,) int, -1 for the root.
        joint_positions: (T,31,3) float32 world joint-head positions, metres, Z up.
        joint_rotations: (T,31,3,3) float32 world rotations of each joint's frame (Anny's
            bone frame: Y along the bone), i.e. the rotation part of the joint world transform.
        joint_rotations_from_apose: (T,31,3,3) float32 world rotations relative to the A-pose.
        root_translation: (T,3) float32 world position of the Hips head.
        fps: float; name: str; body: str (phenotype values).
    """
    path = Path(path)
    if path.suffix != ".npz":
        raise ParameterError(f"{path}: the motion output must end in .npz")
    posed = body.pose(motion.joint_rotations, motion.root_translation, with_vertices=False)
    arrays = {
        "joint_names": np.array(JOINT_NAMES),
        "joint_parents": np.array(JOINT_PARENTS, dtype=np.int64),
        "joint_positions": posed.joint_positions.numpy().astype(np.float32),
        "joint_rotations": posed.joint_world_transforms[..., :3, :3].numpy().astype(np.float32),
        "joint_rotations_from_apose": motion.joint_rotations.numpy().astype(np.float32),
        "root_translation": motion.root_translation.numpy().astype(np.float32),
        "fps": np.float64(motion.fps),
        "name": np.array(motion.name),
        "body": np.array(body.shape.label()),
    }
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return path
