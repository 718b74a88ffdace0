"""Exporters: OBJ sequences, PC2 point caches, USD stages, binary glTF and the ``frames.npz`` contract.

All writers validate their input (``ParameterError``) and write atomically.
Coordinates are metres, Z up, unless an ``up``/``up_axis`` option converts them.
"""

from hyperbones.export.frames import FRAMES_KEYS, read_frames_npz, write_frames_npz
from hyperbones.export.gltf import write_gltf
from hyperbones.export.obj_sequence import write_obj_sequence
from hyperbones.export.pc2 import read_pc2, write_pc2
from hyperbones.export.scene_mesh import SceneMesh
from hyperbones.export.usd import write_usd

__all__ = [
    "FRAMES_KEYS",
    "SceneMesh",
    "read_frames_npz",
    "read_pc2",
    "write_frames_npz",
    "write_gltf",
    "write_obj_sequence",
    "write_pc2",
    "write_usd",
]
