"""The teacher (Module C) as a simulation method: an autoregressive rollout over any length,
each step one network call (``models.teacher.teacher_step``); the start, the settling step
and the per-step strain limiting and contact are ``runtime.teacher_rollout.StepRollout``'s.
"""

from __future__ import annotations

from pathlib import Path

import torch

from hyperbones.body.anny_body import Body
from hyperbones.devices import pick_device
from hyperbones.errors import ParameterError
from hyperbones.garment.garment import Garment
from hyperbones.models.cloth_graph import GarmentTopology
from hyperbones.models.loading import SHIPPED_TEACHER, teacher_from_checkpoint
from hyperbones.models.teacher import Teacher, teacher_step
from hyperbones.physics.material import Material
from hyperbones.runtime.teacher_rollout import StepRollout


class TeacherMethod(StepRollout):
    """Garment positions rolled out by a trained teacher checkpoint."""

    name = "teacher"

    def __init__(self, garment: Garment, body: Body, rest_vertices: torch.Tensor, material: Material | None = None,
                 checkpoint: str | Path | None = None, device: str = "auto", progress: bool = False,
                 model: Teacher | None = None, settle_dt: float | None = None):
        """``model`` (with ``settle_dt``, the length of the first step, as its training data
        config says) rolls out a teacher in memory, e.g. the one being trained; otherwise
        ``checkpoint`` (default: the shipped one), whose config gives ``settle_dt``."""
        self.device = pick_device(device)
        if model is not None:
            if settle_dt is None:
                raise ParameterError("TeacherMethod(model=...) needs settle_dt (the training config's data.settle_dt)")
            self.model, self.settle_dt = model, float(settle_dt)
        else:
            if checkpoint is None and not SHIPPED_TEACHER.exists():
                raise ParameterError("no trained teacher ships with this version yet: train one with `hyperbones "
                                     "train` and pass --checkpoint FILE")
            self.model, payload = teacher_from_checkpoint(checkpoint or SHIPPED_TEACHER, self.device)
            self.settle_dt = float(payload["config"]["data"]["settle_dt"])
        material = material or garment.material
        rest = self._prepare_cloth(garment, body, rest_vertices, material, progress)
        self.topology = GarmentTopology.build(rest.rest_vertices, garment.faces, garment.pinned, rest.vertex_masses,
                                              material).to(self.device)

    def _step(self, positions, velocities, pinned_next, body_now, body_next, nearest, dt):
        return teacher_step(self.model, self.topology, self.rest, positions, velocities, pinned_next, body_now,
                            body_next, self.body_faces, nearest, dt)
