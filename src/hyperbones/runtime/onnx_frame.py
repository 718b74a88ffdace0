"""One character's per-frame runtime as a pure function of its inputs and carried state, for
an exported graph (ONNX): what ``Simulator.step`` does for one identity without contact.

The body contact (a nearest-face search over the posed body, push-out, edge projection) is
not in the graph: its search is a BVH query with data-dependent work per vertex, which ONNX
cannot express; an engine runs its own (README, "Running the runtime in an engine").
Everything else is: forward kinematics from the 31 joints, the virtual bones, Module A
(Bone-Net, skinning, the UV raster and Conv-MLP, sampling; this identity's Module B encoding
and maps are constants) and the follow of the last frame. The frame counter in the state
replaces ``Simulator``'s "no last frame yet" branches (the first frame fills the bone window
and is not followed; the second follows without the carried lag).
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import torch
from torch import nn

from hyperbones.errors import ParameterError
from hyperbones.geometry.rotations import rigid_inverse
from hyperbones.io_utils import atomic_path
from hyperbones.runtime.simulator import (IdentityBatch, Simulator, module_a_frame, pose_characters,
                                          transform_points)

OPSET = 18
# Settings the graph cannot hold or the engine does not want: contact is the engine's; the
# Conv-MLP runs in float32 (an engine picks its own precision).
ONNX_OVERRIDES = {"contact": False, "bfloat16": False}
INPUTS = ("joint_rotations", "root_translation", "bone_window", "last_vertices", "last_to_local", "last_motion",
          "frame")
OUTPUTS = ("vertices", "next_bone_window", "next_last_vertices", "next_last_to_local", "next_last_motion",
           "next_frame")


class RuntimeFrame(nn.Module):
    """``forward(joint_rotations (31,3,3), root_translation (3,), bone_window (K,B,3),
    last_vertices (V,3), last_to_local (4,4), last_motion (4,4), frame (1,))`` -> the
    garment's (V,3) world vertices at this frame and the next state (same shapes; ``frame``
    + 1). The first state: ``initial_state()``. Float32 throughout."""

    def __init__(self, simulator: Simulator):
        super().__init__()
        if len(simulator.identities) != 1:
            raise ParameterError(f"a RuntimeFrame runs one character, the simulator has {len(simulator.identities)}")
        if simulator.contact is not None:
            raise ParameterError("a RuntimeFrame has no body contact: make the simulator with contact=false")
        if simulator.device.type != "cpu":
            raise ParameterError("a RuntimeFrame is made from a CPU simulator")
        identity = simulator.identities[0]
        self.module_a = simulator.module_a
        self.batch = IdentityBatch.of([replace(identity, raster=identity.raster.dense())])
        self.config = simulator.config
        self.register_buffer("rest_joints", simulator.rest_joints.clone())  # (1,31,3)
        self.register_buffer("bone_joint_weights", simulator.bone_joint_weights.clone())  # (1,B,31)
        self.register_buffer("bone_rest", simulator.bone_rest.clone())  # (1,B,3)
        self.window_frames = self.module_a.config.window_frames
        self.num_bones = identity.bones.num_bones
        self.num_vertices = identity.num_vertices

    def initial_state(self) -> dict[str, torch.Tensor]:
        """The state before the first frame (its values are not read: ``frame`` 0 says so)."""
        return {"bone_window": torch.zeros(self.window_frames, self.num_bones, 3),
                "last_vertices": torch.zeros(self.num_vertices, 3), "last_to_local": torch.eye(4),
                "last_motion": torch.eye(4), "frame": torch.zeros(1)}

    def forward(self, joint_rotations: torch.Tensor, root_translation: torch.Tensor, bone_window: torch.Tensor,
                last_vertices: torch.Tensor, last_to_local: torch.Tensor, last_motion: torch.Tensor,
                frame: torch.Tensor) -> tuple[torch.Tensor, ...]:
        rotations, positions, to_local = pose_characters(self.rest_joints, self.bone_joint_weights, self.bone_rest,
                                                         joint_rotations[None], root_translation[None])
        first = frame < 0.5  # (1,) the first frame fills the window
        window = torch.where(first, positions.expand(self.window_frames, -1, -1),
                             torch.cat([bone_window[1:], positions], dim=0))
        garment = module_a_frame(self.module_a, self.batch, window[None], rotations, positions, to_local,
                                 conv_mlp=self.config.conv_mlp, invert=rigid_inverse)[0]
        motion = rigid_inverse(to_local[0]) @ last_to_local  # (4,4) the heading frames' motion
        settings = self.config
        if settings.follows:
            lagged = motion + settings.carry_lag * (last_motion - motion)
            carrier = torch.where(frame < 1.5, motion, lagged)  # the second frame has no last motion
            carried = transform_points(carrier, last_vertices)
            followed = carried + settings.follow * (garment - carried)
            vertices = torch.where(first, garment, followed)
        else:
            vertices = garment
        return vertices, window, vertices, to_local[0], motion, frame + 1.0


def example_inputs(frame: RuntimeFrame) -> tuple[torch.Tensor, ...]:
    """The graph's inputs at the rest pose, first frame (the shapes it is traced with)."""
    state = frame.initial_state()
    return (torch.eye(3).expand(31, 3, 3).contiguous(), frame.rest_joints[0, 0].clone(), state["bone_window"],
            state["last_vertices"], state["last_to_local"], state["last_motion"], state["frame"])


def write_onnx(frame: RuntimeFrame, path: str | Path) -> Path:
    """``frame`` as one self-contained ONNX file (opset 18, weights inside) at ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp, torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the exporter's notes on its own internals
        torch.onnx.export(frame, example_inputs(frame), str(tmp), dynamo=True, opset_version=OPSET,
                          input_names=list(INPUTS), output_names=list(OUTPUTS), external_data=False, verbose=False)
    return path
