"""The whole HyperBones network: Module C (teacher, with the shared trunk), B and A.

Module B runs the teacher's trunk (the same parameters, held once, by the teacher) on the
canonical graph, so physics gradients on C shape B's identity encoding (paper Sec. 3.5).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import torch
from torch import nn

from hyperbones.models.cloth_graph import ClothGraph
from hyperbones.models.module_a import ModuleA, ModuleAConfig
from hyperbones.models.module_b import IdentityCode, ModuleB
from hyperbones.models.normalizer import frozen_statistics
from hyperbones.models.teacher import Teacher, TrunkConfig


@dataclass(frozen=True)
class HyperBonesConfig:
    """trunk: the shared MeshGraphNet; runtime: Module A (its bone count, d_z and d_f size Module B's heads)."""

    trunk: TrunkConfig = field(default_factory=TrunkConfig)
    runtime: ModuleAConfig = field(default_factory=ModuleAConfig)

    def as_dict(self) -> dict:
        return {"trunk": asdict(self.trunk), "runtime": asdict(self.runtime)}

    @classmethod
    def from_dict(cls, values: dict) -> "HyperBonesConfig":
        return cls(TrunkConfig(**values.get("trunk", {})), ModuleAConfig.from_dict(values.get("runtime", {})))


class HyperBonesModel(nn.Module):
    """teacher (Module C, owner of the trunk), encoder (Module B's heads), runtime (Module A)."""

    def __init__(self, config: HyperBonesConfig = HyperBonesConfig()):
        super().__init__()
        self.config = config
        self.teacher = Teacher(config.trunk)
        self.encoder = ModuleB(config.trunk.latent, config.runtime.num_bones, config.runtime.shape_code,
                               config.runtime.uv_features)
        self.runtime = ModuleA(config.runtime)

    @classmethod
    def from_payload(cls, payload: dict) -> "HyperBonesModel":
        """The model of a joint training checkpoint (its weights' moving average when it keeps
        one), in eval mode. payload: ``training.checkpoint.load_checkpoint``'s result."""
        config = payload["config"]
        model = cls(HyperBonesConfig.from_dict({"trunk": config["model"], "runtime": config["runtime"]}))
        model.load_state_dict(payload.get("ema") or payload["model"])
        return model.eval()

    def trunk_latents(self, graph: ClothGraph, train_trunk: bool = True) -> torch.Tensor:
        """The shared trunk over the canonical graph: the garment nodes' latents (V,latent).

        The canonical graph (still body, zero velocities) is not a state C steps from, so it
        never adds to the trunk's input statistics. ``train_trunk`` False runs the trunk
        without gradient.
        """
        with frozen_statistics(self.teacher), torch.set_grad_enabled(train_trunk and torch.is_grad_enabled()):
            return self.teacher.encode(graph)[: graph.num_garment]

    def encode(self, graph: ClothGraph, train_trunk: bool = True, latents: torch.Tensor | None = None) -> IdentityCode:
        """Module B: the trunk over the canonical graph, then the heads on the garment nodes.

        ``train_trunk`` False: a loss on B's output trains B's heads only. ``latents``: the
        trunk's output for this graph, computed before (a frozen trunk's never changes).
        """
        return self.encoder(self.trunk_latents(graph, train_trunk) if latents is None else latents)
