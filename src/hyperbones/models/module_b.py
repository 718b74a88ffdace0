"""Module B: the identity encoder (paper Sec. 3.3), run once per body shape × garment.

The canonical graph goes through the trunk shared with the teacher (``HyperBonesModel.encode``:
the teacher's own weights, so physics gradients reach it through Module C during training);
the three heads here read the garment nodes' latents F_c (V,latent):

  shape code z     mean over the garment nodes, then a 2-layer MLP -> (d_z,)
  Δw               per vertex, MLP latent -> 64 -> B: corrections of the log initial weights
  f_v              per vertex, linear latent -> d_f: rasterised once into F_UV

The Δw and f_v heads start at zero (at first the weights are the geodesic ones and F_UV
carries nothing).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn



@dataclass
class IdentityCode:
    """What Module B gives Module A for one identity: z (d_z,), Δw (V,B), f_v (V,d_f)."""

    shape_code: torch.Tensor
    weight_corrections: torch.Tensor
    vertex_features: torch.Tensor


class ModuleB(nn.Module):
    """The heads of Module B: garment-node latents (V,latent) of the shared trunk -> ``IdentityCode``."""

    def __init__(self, latent: int, num_bones: int = 128, shape_code: int = 128, uv_features: int = 32):
        super().__init__()
        self.shape_head = nn.Sequential(nn.Linear(latent, shape_code), nn.ReLU(), nn.Linear(shape_code, shape_code))
        self.weight_head = nn.Sequential(nn.Linear(latent, 64), nn.ReLU(), nn.Linear(64, num_bones))
        self.feature_head = nn.Linear(latent, uv_features)
        for layer in (self.weight_head[-1], self.feature_head):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)

    def forward(self, latents: torch.Tensor) -> IdentityCode:
        return IdentityCode(self.shape_head(latents.mean(0)), self.weight_head(latents), self.feature_head(latents))
