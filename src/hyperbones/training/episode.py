"""One training identity (a garment on a body in a fabric) and an episode on it, in torch alone.

What ``TeacherData`` (Anny, Warp, the drape) and ``PackData`` (a training pack) both hand the
trainers: the cloth's rest state, graph topology and strain limiter of an identity, and a
window of the body's motion with the garment skinned along it. Nothing here imports Anny or
Warp, so the torch-only trainer (``training.from_pack``) runs where neither is installed.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.models.cloth_graph import GarmentTopology
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.energies import GRAVITY
from hyperbones.physics.material import Material, sample_material
from hyperbones.physics.strain_limit import StrainLimiter

if TYPE_CHECKING:
    from hyperbones.body.anny_body import Body
    from hyperbones.body.rig import BodyRig
    from hyperbones.garment.garment import Garment


@dataclass
class Identity:
    """One garment on one body with one fabric: what the physics and the graph need.

    rest: the cloth's rest state (float32); topology: the graph's fixed part;
    skin_weights: (V,31) LBS weights of the canonical garment (pinned vertices follow them);
    limiter: the strain limiting applied to each step's result (``physics.strain_limit``);
    garment: the ``Garment`` itself on this body (what Module B encodes and rollouts start
    from): at its rest shape, or settled on the body when ``draped``.
    """

    name: str
    body: Body | BodyRig  # what poses it: the Anny body, or its rig alone (a training pack)
    rest: ClothRest
    topology: GarmentTopology
    skin_weights: torch.Tensor
    limiter: StrainLimiter
    garment: Garment | None = None  # the garment carried to this body (UVs, pins, fabric), when known
    resolution: int | None = None  # the template resolution it was made from, when sampled by TeacherData
    draped: bool = False  # garment is the carried garment settled on the body (data.drape)

    @classmethod
    def build(cls, name: str, body: Body | BodyRig, rest_vertices: torch.Tensor, faces: torch.Tensor, pinned: torch.Tensor,
              skin_weights: torch.Tensor, material: Material, garment: Garment | None = None,
              resolution: int | None = None, draped: bool = False) -> "Identity":
        rest = ClothRest.from_mesh(rest_vertices.float(), faces, material)
        topology = GarmentTopology.build(rest.rest_vertices, faces, pinned, rest.vertex_masses, material)
        return cls(name, body, rest, topology, skin_weights, StrainLimiter.for_cloth(rest, topology.pinned_mask),
                   garment, resolution, draped)

    def skin(self, skinning_transforms: torch.Tensor, vertices: torch.Tensor | None = None) -> torch.Tensor:
        """(T,31,4,4) body skinning transforms -> (T,V,3) the garment by LBS, on their device:
        its rest shape, or ``vertices`` (V,3), the same garment elsewhere on the canonical body
        (its drape)."""
        canonical = self.rest.rest_vertices if vertices is None else vertices
        return linear_blend_skinning(canonical.to(skinning_transforms),
                                     self.skin_weights.to(skinning_transforms), skinning_transforms)


@dataclass
class Episode:
    """A window of frames s−1 … s+K of a motion on one identity.

    body_vertices: (K+2,Vb,3); garment_lbs: (K+2,V,3) the garment skinned along (its
    pinned rows are where pinned vertices must be). Step k goes from frame k+1 to k+2.
    """

    identity: Identity
    body_vertices: torch.Tensor
    garment_lbs: torch.Tensor
    motion: str

    @property
    def num_steps(self) -> int:
        return self.body_vertices.shape[0] - 2


def ballistic_hops(num_frames: int, fps: float, rng: random.Random,
                   speeds: tuple[float, float] = (0.8, 2.2)) -> torch.Tensor:
    """(num_frames,) heights (m) of hops in free fall, to add to a clip's root.

    Hops follow one another after random pauses (0.2–0.6 s; the first after 0–0.5 s): each
    leaves the ground at a speed drawn from ``speeds`` and flies a parabola under gravity
    back to height 0. The path is then smoothed by a 5-frame binomial kernel, which spreads
    take-off and landing over ~0.15 s (2–3 g, as in the CMU jumps) and leaves the flight's
    curvature at exactly −g.
    """
    heights = torch.zeros(num_frames + 4, dtype=torch.float64)  # 2 frames of padding each side
    dt = 1.0 / fps
    frame = 2 + int(rng.uniform(0.0, 0.5) * fps)
    while frame < num_frames + 2:
        speed = rng.uniform(*speeds)
        flight = int(2 * speed / GRAVITY * fps)
        tau = torch.arange(1, flight + 1, dtype=torch.float64) * dt
        arc = (speed * tau - GRAVITY * tau ** 2 / 2).clamp_min(0.0)[: len(heights) - frame - 1]
        heights[frame + 1: frame + 1 + len(arc)] = arc
        frame += 1 + flight + int(rng.uniform(0.2, 0.6) * fps)
    kernel = torch.tensor([1.0, 4.0, 6.0, 4.0, 1.0], dtype=torch.float64) / 16
    return torch.nn.functional.conv1d(heights[None, None], kernel[None, None])[0, 0].float()


class EpisodeDraws:
    """The draws ``TeacherData`` and ``PackData`` share: a fabric and a clip window. They
    set ``random`` (``random.Random``), ``config`` (``DataConfig``), ``motions`` (each with
    ``num_frames`` and ``slice``) and ``default_body`` (with ``leg_length``)."""

    def sample_material(self) -> Material:
        """HOOD's default fabric for ``data.default_material_fraction`` of draws, else one over HOOD's ranges."""
        if self.random.random() < self.config.default_material_fraction:
            return Material()
        return sample_material(self.random.random)

    def sample_window(self, frames: int, identity: Identity, at_end: bool = False):
        """A random training motion cut to ``frames`` frames (fewer if it is shorter), ending
        where it ends (its hold) when ``at_end``; and its root path (T,3) scaled to
        ``identity``'s leg length."""
        motion = self.random.choice(self.motions)
        frames = min(frames, motion.num_frames)
        start = motion.num_frames - frames if at_end else self.random.randrange(0, motion.num_frames - frames + 1)
        window = motion.slice(start, start + frames)
        return window, window.root_translation * (identity.body.leg_length / self.default_body.leg_length)


__all__ = ["Episode", "EpisodeDraws", "Identity", "ballistic_hops"]
