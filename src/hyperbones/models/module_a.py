"""Module A: the per-frame runtime network (paper Sec. 3.2).

Per frame, for a batch of N characters that share the bone count B:

  bone window (N,K,B,3), bone codes (N,B,C) ──Bone-Net (FiLM by z)──> ΔT (N,B,9), pose embedding φ (N,P)
  bone frames + ΔT ──garment LBS with the identity's weights──> Stage-1 garment (V,3)
  [P_UV | coverage | F_UV | φ] (N,C,R,R) ──Conv-MLP──> displacement image (N,3,R,R) ──> δp (V,3)

Everything here lives in the character's local frame (``heading_frame``): origin at the
Hips, Z up, X/Y turned with the character's heading. The network therefore sees the same
input for the same motion in any place and facing direction, and gravity stays along −Z.

Input window: the bones' positions at t and their frame-to-frame displacements over the last
K frames (``window_frames``; the paper's K = 3: (t−1)−(t−2) and t−(t−1), first and second
differences). The positions at t−1 … t−K+1 are these minus the displacements, so this is the
paper's input without its redundant copies. Positions are in metres, displacements in
centimetres per frame (both of order one). A window longer than the paper's lets the output
keep changing for K−1 frames after the body stops: with K = 3 a still body freezes the
garment two frames later, so no swing after a stop can be expressed.

Bone-Net comes in two forms (``bone_net``):
  - "per-bone" (default): one MLP shared by every bone, on that bone's own window and its
    *bone code* (which body joints drive it, where it sits on the canonical body, Module B's
    feature of its garment vertex), with the bones' mean hidden state added as context
    (a DeepSets layer). Its output for a bone depends on what the bone is, not on its index.
  - "global": the paper's single MLP on all bones' windows at once, one output slot per
    bone index. Bones are placed by farthest point sampling on each fitted garment, so
    index b is a different place on every identity: what this form learns for one bone
    slot does not carry to the same place on another identity, only what all bones share
    (a common sag or lag) does.
  The per-bone form is the default because its output does not depend on the bone order,
  count or garment resolution (the comparison: docs/experiments/*-per-bone-bone-net.md).

Corrections: the 6D rotation of each bone frame (first two columns of its rotation) gets
Δ6D added before Gram–Schmidt (the paper's rule), its position Δt (the network's output in
centimetres). The last layers of Bone-Net, the Shape Modulator and the Conv-MLP start at
zero, so an untrained Module A is plain virtual-bone skinning.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import roma
import torch
from torch import nn

from hyperbones.body.skeleton import NUM_JOINTS
from hyperbones.errors import ParameterError
from hyperbones.motion.motion import heading_angle

CENTIMETRE = 0.01
BONE_NETS = ("per-bone", "global")


@dataclass(frozen=True)
class ModuleAConfig:
    """Sizes of Module A (paper defaults except the UV resolution, see ``uv_resolution``).

    num_bones: B virtual bones.  shape_code: d_z.  hidden/layers: Bone-Net (4 × 256).
    pose_embedding: channels of the broadcast pose embedding φ.  uv_features: d_f of F_UV.
    uv_resolution: R of the UV maps (paper 512; smaller costs less per frame on a CPU).
    window_frames: K frames of bone motion Bone-Net sees (paper 3).
    conv_channels: the Conv-MLP's hidden widths (64, 128, 64), then 3.
    use_conv: False drops Stage 2 (the "no Conv-MLP" ablation).
    bone_net: "per-bone" (one MLP shared by the bones) or "global" (the paper's; see the
    module docstring). Checkpoints from before the choice existed are "global".
    """

    num_bones: int = 128
    shape_code: int = 128
    hidden: int = 256
    layers: int = 4
    pose_embedding: int = 16
    uv_features: int = 32
    uv_resolution: int = 128
    conv_channels: tuple[int, int, int] = (64, 128, 64)
    use_conv: bool = True
    window_frames: int = 3
    bone_net: str = "per-bone"

    def __post_init__(self):
        if self.bone_net not in BONE_NETS:
            raise ParameterError(f"runtime.bone_net must be one of {', '.join(BONE_NETS)}, got {self.bone_net!r}")
        if self.window_frames < 2:
            raise ParameterError(f"runtime.window_frames must be at least 2 (a position and a velocity), "
                                 f"got {self.window_frames}")

    @property
    def window_features(self) -> int:
        """Bone-Net's input width: 3 numbers per bone for its position at t and for each of
        its K−1 displacements."""
        return 3 * self.window_frames * self.num_bones

    @property
    def bone_code_features(self) -> int:
        """C of a bone code: joint weights (31), canonical position from the Hips (3), f_v (d_f)."""
        return NUM_JOINTS + 3 + self.uv_features

    @classmethod
    def from_dict(cls, values: dict) -> "ModuleAConfig":
        """From ``asdict``'s output as a checkpoint stores it (lists back to tuples)."""
        values = dict(values)
        if "conv_channels" in values:
            values["conv_channels"] = tuple(values["conv_channels"])
        values.setdefault("bone_net", "global")  # saved before the per-bone form existed
        return cls(**values)


def heading_frame(root_rotation: torch.Tensor, root_position: torch.Tensor) -> torch.Tensor:
    """(...,3,3) Hips rotation (relative to the A-pose), (...,3) Hips position -> (...,4,4) world -> local.

    The local frame has its origin at the Hips and is turned about Z by the character's
    heading (the A-pose faces −Y), so local −Y is where the character faces.
    """
    angle = heading_angle(root_rotation)
    cos, sin, zero, one = angle.cos(), angle.sin(), torch.zeros_like(angle), torch.ones_like(angle)
    x, y, z = root_position.unbind(-1)
    # rot_z(angle) transposed, then the translation that takes the Hips to the origin: the
    # matrix written out (a quarter of the time of building it by an axis-angle rotation).
    rows = [cos, sin, zero, -(cos * x + sin * y), -sin, cos, zero, sin * x - cos * y, zero, zero, one, -z,
            zero, zero, zero, one]
    return torch.stack(rows, dim=-1).unflatten(-1, (4, 4))


def bone_window_features(window: torch.Tensor) -> torch.Tensor:
    """(N,K,B,3) local bone positions at t−K+1 … t -> (N, 3·K·B) Bone-Net input:
    the positions at t (m), then per bone its K−1 displacements (cm per frame, oldest first)."""
    displacement = (window[:, 1:] - window[:, :-1]) / CENTIMETRE  # (N,K-1,B,3)
    return torch.cat([window[:, -1].flatten(1), displacement.transpose(1, 2).flatten(1)], dim=1)


def bone_codes(joint_weights: torch.Tensor, rest_positions: torch.Tensor, hips: torch.Tensor,
               vertex_features: torch.Tensor, garment_vertex: torch.Tensor) -> torch.Tensor:
    """What each bone is, for the per-bone Bone-Net: (B,J) body joint weights, (B,3) canonical
    bone positions, (3,) canonical Hips, (V,d_f) Module B's vertex features, (B,) the bones'
    garment vertices -> (B, J+3+d_f): joint weights, position from the Hips (m), f_v."""
    return torch.cat([joint_weights, rest_positions - hips, vertex_features[garment_vertex]], dim=-1)


class ShapeModulator(nn.Module):
    """z (N,d_z) -> FiLM scales and shifts (N,layers,2,hidden): a 3-layer MLP.

    The scale is 1 + the output, and the output layer starts at zero (identity FiLM).
    """

    def __init__(self, config: ModuleAConfig):
        super().__init__()
        self.layers, self.hidden = config.layers, config.hidden
        self.net = nn.Sequential(
            nn.Linear(config.shape_code, config.hidden), nn.ReLU(),
            nn.Linear(config.hidden, config.hidden), nn.ReLU(),
            nn.Linear(config.hidden, 2 * config.layers * config.hidden))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, shape_code: torch.Tensor) -> torch.Tensor:
        film = self.net(shape_code).unflatten(-1, (self.layers, 2, self.hidden))
        return film + torch.tensor([1.0, 0.0], device=film.device)[:, None]


class BoneNet(nn.Module):
    """Bone window features (N,3KB) and FiLM (N,layers,2,hidden) -> ΔT (N,B,9), φ (N,P).

    ΔT per bone: Δ6D (6) then Δt in metres (3).
    """

    def __init__(self, config: ModuleAConfig):
        super().__init__()
        self.num_bones = config.num_bones
        sizes = [config.window_features] + [config.hidden] * config.layers
        self.hidden_layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:]))
        self.corrections = nn.Linear(config.hidden, 9 * config.num_bones)
        self.pose_embedding = nn.Linear(config.hidden, config.pose_embedding)
        nn.init.zeros_(self.corrections.weight)
        nn.init.zeros_(self.corrections.bias)

    def forward(self, features: torch.Tensor, film: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = features
        for index, layer in enumerate(self.hidden_layers):
            h = torch.relu(film[:, index, 0] * layer(h) + film[:, index, 1])
        delta = self.corrections(h).unflatten(-1, (self.num_bones, 9))
        delta = torch.cat([delta[..., :6], delta[..., 6:] * CENTIMETRE], dim=-1)
        return delta, self.pose_embedding(h)


class PerBoneNet(nn.Module):
    """One MLP for all bones: (N,K,B,3) local bone window, (N,B,C) bone codes and FiLM
    (N,layers,2,hidden) -> ΔT (N,B,9), φ (N,P).

    Layer 1 reads a bone's position at t (m), its K−1 displacements (cm per frame) and its
    code; layer 2 also reads the mean of layer 1 over the character's bones (the pose of
    the whole garment); FiLM acts on every hidden layer as in the global form. φ comes from
    the mean of the last hidden layer over the bones.
    """

    def __init__(self, config: ModuleAConfig):
        super().__init__()
        if config.layers < 2:
            raise ParameterError(f"the per-bone Bone-Net needs at least 2 layers, got {config.layers}")
        hidden = config.hidden
        sizes = [3 * config.window_frames + config.bone_code_features, 2 * hidden] + [hidden] * (config.layers - 2)
        self.hidden_layers = nn.ModuleList(nn.Linear(size, hidden) for size in sizes)
        self.corrections = nn.Linear(hidden, 9)
        self.pose_embedding = nn.Linear(hidden, config.pose_embedding)
        nn.init.zeros_(self.corrections.weight)
        nn.init.zeros_(self.corrections.bias)

    def forward(self, window: torch.Tensor, codes: torch.Tensor,
                film: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        displacement = (window[:, 1:] - window[:, :-1]).transpose(1, 2).flatten(2) / CENTIMETRE  # (N,B,3(K-1))
        h = torch.cat([window[:, -1], displacement, codes], dim=-1)
        for index, layer in enumerate(self.hidden_layers):
            if index == 1:
                h = torch.cat([h, h.mean(1, keepdim=True).expand_as(h)], dim=-1)
            h = torch.relu(film[:, index, None, 0] * layer(h) + film[:, index, None, 1])
        delta = self.corrections(h)
        delta = torch.cat([delta[..., :6], delta[..., 6:] * CENTIMETRE], dim=-1)
        return delta, self.pose_embedding(h.mean(1))


def correct_bones(rotations: torch.Tensor, positions: torch.Tensor,
                  delta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Bone frames (...,B,3,3), (...,B,3) and ΔT (...,B,9) -> corrected frames (6D rotations add)."""
    six_d = rotations[..., :, :2] + delta[..., :6].unflatten(-1, (3, 2))
    return roma.special_gramschmidt(six_d), positions + delta[..., 6:]


class ConvRefiner(nn.Module):
    """The Conv-MLP: (N,C_in,R,R) -> (N,3,R,R) displacements in metres.

    Five 3×3 convolutions C_in→64→128→128→64→3 with ReLU; the 128→128 layer is residual.
    """

    def __init__(self, in_channels: int, channels: tuple[int, int, int] = (64, 128, 64)):
        super().__init__()
        first, middle, last = channels
        self.inp = nn.Conv2d(in_channels, first, 3, padding=1)
        self.up = nn.Conv2d(first, middle, 3, padding=1)
        self.mid = nn.Conv2d(middle, middle, 3, padding=1)
        self.down = nn.Conv2d(middle, last, 3, padding=1)
        self.out = nn.Conv2d(last, 3, 3, padding=1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = torch.relu(self.inp(x))
        h = torch.relu(self.up(h))
        h = h + torch.relu(self.mid(h))
        h = torch.relu(self.down(h))
        return self.out(h) * CENTIMETRE


class ModuleA(nn.Module):
    """Shape Modulator + Bone-Net + Conv-MLP (the learnt parts of the runtime)."""

    def __init__(self, config: ModuleAConfig = ModuleAConfig()):
        super().__init__()
        self.config = config
        self.modulator = ShapeModulator(config)
        self.bone_net = PerBoneNet(config) if config.bone_net == "per-bone" else BoneNet(config)
        in_channels = 3 + 1 + config.uv_features + config.pose_embedding
        self.refiner = ConvRefiner(in_channels, config.conv_channels) if config.use_conv else None

    def for_inference(self, device: str | torch.device = "cpu", bfloat16: bool = False) -> "ModuleA":
        """A copy for the per-frame runtime: on ``device``, in eval mode, the Conv-MLP's weights
        channels-last (the layout oneDNN's CPU convolutions and GPUs' tensor cores run fastest)
        and, with ``bfloat16``, in bfloat16 (``refine`` casts its inputs to match). The copy
        leaves this module, which training may still update, as it is. Timings:
        docs/experiments/*-realtime-runtime-2.md."""
        runtime = copy.deepcopy(self).to(device).eval()
        if runtime.refiner is not None:
            runtime.refiner.to(memory_format=torch.channels_last)
            if bfloat16:
                runtime.refiner.to(torch.bfloat16)
        return runtime

    def bone_corrections(self, window: torch.Tensor, codes: torch.Tensor,
                         film: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Bone-Net in either form: (N,K,B,3) local bone window, (N,B,C) bone codes (unused by
        the global form), (N,layers,2,hidden) FiLM -> ΔT (N,B,9), φ (N,P)."""
        if isinstance(self.bone_net, PerBoneNet):
            return self.bone_net(window, codes, film)
        return self.bone_net(bone_window_features(window), film)

    def refine(self, positions_uv: torch.Tensor, coverage: torch.Tensor, features_uv: torch.Tensor,
               pose_embedding: torch.Tensor) -> torch.Tensor:
        """Stage 2 on images: P_UV (N,3,R,R), coverage (N,1,R,R), F_UV (N,d_f,R,R), φ (N,P) -> (N,3,R,R).

        Zero when the config has no Conv-MLP.
        """
        if self.refiner is None:
            return torch.zeros_like(positions_uv)
        n, _, rows, cols = positions_uv.shape
        x = torch.cat([positions_uv, coverage, features_uv,
                       pose_embedding[:, :, None, None].expand(n, pose_embedding.shape[1], rows, cols)], dim=1)
        weight = self.refiner.inp.weight  # its dtype and layout (``for_inference``) are the input's
        if weight.is_contiguous(memory_format=torch.channels_last) and not weight.is_contiguous():
            x = x.contiguous(memory_format=torch.channels_last)
        return self.refiner(x.to(weight.dtype)).to(positions_uv.dtype)
