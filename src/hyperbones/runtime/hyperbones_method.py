"""``--method hyperbones``: the per-frame runtime (Module A) on a cached identity (Module B)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import torch
from tqdm import tqdm

from hyperbones.body.anny_body import Body, PosedBody
from hyperbones.devices import pick_device
from hyperbones.garment.garment import Garment
from hyperbones.physics.material import Material
from hyperbones.runtime.config import RAW
from hyperbones.runtime.simulator import Simulator


class HyperBonesMethod:
    """Garment positions from the per-frame runtime: Module B once, then Module A per frame,
    with the garment following Module A's output, pushed out of the body and its edges pulled
    back to length after each frame (``raw``: Module A's output as it is, the method
    "hyperbones-raw"). ``runtime``: {setting: value} over the checkpoint's ``RuntimeConfig``."""

    def __init__(self, garment: Garment, body: Body, rest_vertices: torch.Tensor | None = None,
                 material: Material | None = None, checkpoint: str | Path | None = None, device: str = "auto",
                 progress: bool = False, uv_resolution: int | None = None, runtime: dict | None = None,
                 raw: bool = False):
        self.device = pick_device(device)
        self.name = "hyperbones-raw" if raw else "hyperbones"
        garment = replace(garment, material=material or garment.material)
        overrides = {**(runtime or {}), **(RAW if raw else {})}
        self.simulator = Simulator.load([(garment, body)], checkpoint, self.device, uv_resolution,
                                        overrides=overrides, rest_vertices=[rest_vertices])
        self.runtime_config = self.simulator.config
        self.progress = progress

    def run(self, posed: PosedBody) -> torch.Tensor:
        """(T frames of a posed body) -> (T,V,3) garment positions on the CPU."""
        frames = self.frames(posed)
        return torch.stack([frame.cpu() for frame in tqdm(frames, total=posed.joint_rotations.shape[0],
                                                         desc="hyperbones", disable=not self.progress, unit="frame")])

    def frames(self, posed: PosedBody) -> Iterator[torch.Tensor]:
        """Yield each frame's (V,3) garment positions as it is computed (the motion starts at rest)."""
        self.simulator.reset()
        roots = posed.joint_positions[:, 0]
        for t in range(posed.joint_rotations.shape[0]):
            bodies = posed.vertices[t:t + 1] if self.simulator.contact is not None else None
            yield self.simulator.step(posed.joint_rotations[t:t + 1], roots[t:t + 1], bodies)[0]
