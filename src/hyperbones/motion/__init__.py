"""Motion: the Motion type, BVH import and retargeting, foot lock, built-in clips, export."""

from hyperbones.motion.builtin import BUILTINS, builtin_motion
from hyperbones.motion.export import save_motion_npz
from hyperbones.motion.load import DEFAULT_BLEND_IN, load_motion
from hyperbones.motion.motion import DEFAULT_FPS, Motion
from hyperbones.motion.retarget import retarget_bvh

__all__ = ["BUILTINS", "DEFAULT_BLEND_IN", "DEFAULT_FPS", "Motion", "builtin_motion", "load_motion",
           "retarget_bvh", "save_motion_npz"]
