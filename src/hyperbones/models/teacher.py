"""Module C: the HOOD-style teacher. The shared trunk on the dynamic body–garment graph, a
decoder to per-vertex acceleration, and symplectic Euler (REFERENCE.md; paper Sec. 3.4).

The decoder predicts a physical acceleration in units of g; a step of length dt turns it
into a change of per-step displacement a = ĝ·g·dt², so the long settling step and the
1/30 s steps share one output scale. State units are per step: v is the displacement of
the last step (m). One step: v(t+1) = v(t) + a, x(t+1) = x(t) + v(t+1); pinned vertices
are put where the body takes them.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from hyperbones.models.cloth_graph import EDGE_FEATURES, NODE_FEATURES, ClothGraph
from hyperbones.models.mgn import EdgeSet, MeshGraphNet, mlp
from hyperbones.models.normalizer import Normalizer


@dataclass(frozen=True)
class TrunkConfig:
    """Size of the shared MeshGraphNet trunk (paper: latent 128, 15 blocks)."""

    latent: int = 128
    blocks: int = 15


class Teacher(nn.Module):
    """Graph -> (V,3) garment accelerations in units of g (garment nodes only)."""

    def __init__(self, config: TrunkConfig = TrunkConfig()):
        super().__init__()
        self.config = config
        self.node_normalizer = Normalizer(NODE_FEATURES)
        self.edge_normalizers = nn.ModuleDict({"mesh": Normalizer(EDGE_FEATURES), "world": Normalizer(EDGE_FEATURES)})
        self.trunk = MeshGraphNet(NODE_FEATURES, {"mesh": EDGE_FEATURES, "world": EDGE_FEATURES},
                                  latent=config.latent, num_blocks=config.blocks)
        self.decoder = mlp(config.latent, 3, config.latent, layer_norm=False)
        # Start near zero acceleration (the garment coasts) instead of random centimetre kicks.
        with torch.no_grad():
            self.decoder[-1].weight.mul_(0.01)
            self.decoder[-1].bias.zero_()

    def encode(self, graph: ClothGraph) -> torch.Tensor:
        """(N,latent) node latents of the graph (what Module B reads on the canonical graph)."""
        edge_sets = {name: EdgeSet(s.senders, s.receivers, self.edge_normalizers[name](s.features))
                     for name, s in graph.edge_sets.items()}
        return self.trunk(self.node_normalizer(graph.node_features), edge_sets)

    def forward(self, graph: ClothGraph) -> torch.Tensor:
        latents = self.encode(graph)[: graph.num_garment]
        return self.decoder(latents)


class Autocast(nn.Module):
    """``module`` called under ``torch.autocast`` in ``dtype`` (bfloat16): matrix products in
    that precision, its output back in float32. Only the network: what builds its inputs (the
    cloth's internal forces) and what reads its output (integration, the loss) stay float32."""

    def __init__(self, module: nn.Module, dtype: torch.dtype = torch.bfloat16):
        super().__init__()
        self.module, self.dtype = module, dtype

    def forward(self, *args):
        device = next(self.module.parameters()).device
        with torch.autocast(device_type=device.type, dtype=self.dtype):
            return self.module(*args).float()


def integrate(positions: torch.Tensor, velocities: torch.Tensor, acceleration: torch.Tensor,
              pinned_mask: torch.Tensor, pinned_next: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Symplectic Euler in per-step units: (V,3) ×3, (V,) mask, (V,3) -> x(t+1), v(t+1).

    Pinned vertices go to ``pinned_next`` and take the displacement that got them there.
    """
    velocities_next = velocities + acceleration
    positions_next = positions + velocities_next
    pinned = pinned_mask[:, None]
    positions_next = torch.where(pinned, pinned_next, positions_next)
    velocities_next = torch.where(pinned, pinned_next - positions, velocities_next)
    return positions_next, velocities_next


def teacher_step(model: nn.Module, topology, rest, positions: torch.Tensor, velocities: torch.Tensor,
                 pinned_next: torch.Tensor, body_now: torch.Tensor, body_next: torch.Tensor,
                 body_faces: torch.Tensor, nearest, dt: float) -> tuple[torch.Tensor, torch.Tensor]:
    """One step t -> t+1 of the teacher: graph, accelerations, integration.

    topology: ``GarmentTopology``; rest: the garment's ``ClothRest`` (for its internal forces);
    positions, velocities: (V,3) state at t (per-step displacement); pinned_next: (V,3);
    body_now/body_next: (Vb,3); nearest: ``BodyProximity.query(positions)`` at t.
    Returns x(t+1), v(t+1), both (V,3).
    """
    from hyperbones.models.cloth_graph import build_graph, internal_acceleration
    from hyperbones.physics.energies import GRAVITY

    graph = build_graph(topology, positions, velocities, pinned_next, body_now, body_next, body_faces, nearest, dt,
                        internal_acceleration=internal_acceleration(positions, rest))
    change = model(graph) * (GRAVITY * dt * dt)
    return integrate(positions, velocities, change, topology.pinned_mask, pinned_next)
