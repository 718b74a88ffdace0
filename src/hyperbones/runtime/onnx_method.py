"""``--method hyperbones-onnx``: the exported per-frame graph (``runtime.onnx_frame``) run by
onnxruntime on the CPU, as an engine would run it (no body contact: see that module)."""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import torch

from hyperbones.body.anny_body import Body, PosedBody
from hyperbones.garment.garment import Garment
from hyperbones.physics.material import Material
from hyperbones.runtime.onnx_frame import INPUTS, ONNX_OVERRIDES, RuntimeFrame, write_onnx
from hyperbones.runtime.simulator import Simulator


class OnnxRuntimeMethod:
    """Garment positions from the ONNX graph of this garment and body, frame by frame.

    The graph is exported once (Module B's encoding and the UV maps inside) to a temporary
    file and loaded into an onnxruntime CPU session with its default threads."""

    def __init__(self, garment: Garment, body: Body, rest_vertices: torch.Tensor | None = None,
                 material: Material | None = None, checkpoint: str | Path | None = None, device: str = "cpu",
                 progress: bool = False, uv_resolution: int | None = None, runtime: dict | None = None):
        import onnxruntime

        self.name = "hyperbones-onnx"
        self.device = torch.device("cpu")
        garment = replace(garment, material=material or garment.material)
        simulator = Simulator.load([(garment, body)], checkpoint, "cpu", uv_resolution,
                                   overrides={**(runtime or {}), **ONNX_OVERRIDES}, rest_vertices=[rest_vertices])
        self.runtime_config = simulator.config
        self.frame = RuntimeFrame(simulator).eval()
        with tempfile.TemporaryDirectory(prefix="hyperbones-onnx-") as folder:
            path = write_onnx(self.frame, Path(folder) / "runtime.onnx")
            self.session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])

    def run(self, posed: PosedBody) -> torch.Tensor:
        """(T frames of a posed body) -> (T,V,3) garment positions."""
        return torch.stack(list(self.frames(posed)))

    def frames(self, posed: PosedBody) -> Iterator[torch.Tensor]:
        """Yield each frame's (V,3) garment positions (the motion starts at rest)."""
        state = [value.numpy() for value in self.frame.initial_state().values()]
        rotations = posed.joint_rotations.detach().float().numpy()
        roots = posed.joint_positions[:, 0].detach().float().numpy()
        for t in range(rotations.shape[0]):
            outputs = self.session.run(None, dict(zip(INPUTS, [rotations[t], roots[t], *state])))
            state = outputs[1:]
            yield torch.from_numpy(outputs[0])
