"""The per-frame runtime: Module A on cached identities, several characters per batch.

Per frame and character the cost is fixed: forward kinematics of 31 joints and the bones'
skinning blend (on the CPU for all characters at once: a few hundred numbers, which on a
GPU would cost more in kernel launches than in work), one Bone-Net pass (batched over
characters), one (V,B)@(B,12) garment skinning, two sparse products to and from the UV
image and the Conv-MLP (batched). Module A keeps no state but the last K frames of bone
positions, so it does not grow with the motion. Given the posed bodies, ``step`` also pushes garment
vertices that end up inside a body back out and pulls the garment's edges back towards their
rest lengths (``runtime.contact``, ``runtime.isometry``).

Follow (``follow``, ``loose_follow`` < 1): Module A's output is a target the garment moves
towards, not where it is put. Each frame, the garment is first carried from where the last
frame left it: loose cloth with the character (rigidly with its heading frame: origin at the
Hips, turned with the character), cloth on the skin with the skin under it (the displacement
of its nearest skin point), blended from one to the other between ``FOLLOW_FAR`` and
``FOLLOW_NEAR`` from the skin. Each vertex then goes a share of the way from there to Module
A's output, before contact and projection: ``follow`` on the skin, ``loose_follow`` for loose
cloth, blended in the same band (``follow`` everywhere when ``step`` gets no bodies). The
cloth lags and settles as a damped first-order system with a time constant of
(1 − share)/share frames relative to what carries it, which cuts the frame-to-frame jerks
Module A copies from the skeleton (the inertia energy) and starts the projection from the
last, nearly isometric, state; cloth on a limb moves with the limb instead of being pushed
through by it, loose cloth lags longer and settles later after the body stops (it decays, it
does not oscillate).

What carries loose cloth is not the character's motion since the last frame but its blend
with the motion the frame before (``carry_lag`` of the latter; a linear blend of two
frame-to-frame rigid transforms, which differ by a few millimetres and degrees): loose cloth
takes up the character's accelerations (the Hips' bob and sway, a turn starting) over two
frames instead of one. The state is one (V,3) array and two 4×4 transforms per character.

The shares were chosen on training clips with unseen bodies (16_07, 02_03 × two eval body
shapes, 1500 vertices; mean ε_e / ε_a % over dress, long-skirt, tshirt, pants; LBS inertia ÷
ours, mean over the four; hem: ``check-hem``, seconds the dress hem moves after the stop;
carry_lag 0):

| follow / loose_follow | ε_e | ε_a | LBS ÷ inertia | hem (s) |
|---|---:|---:|---:|---:|
| 0.6 / 0.6 | 3.47 | 3.97 | 1.20 | 0.30 |
| **0.6 / 0.4** | 3.40 | 3.92 | 1.17 | 0.33 |
| 0.6 / 0.3 | 3.41 | 3.97 | 1.11 | 0.37 |
| 0.6 / 0.2 | 3.47 | 4.07 | 1.02 | 0.40 |

``carry_lag`` 0.5 against 0 on the same set: ε_e / ε_a 3.40 / 3.94 against 3.40 / 3.92 %,
LBS ÷ inertia 1.20 against 1.17 (long skirt 1.29 against 1.22). On 16_07 with the default
body, dress / long-skirt inertia for carry_lag 0, 0.3, 0.5, 0.7: 6.97 / 8.89, 6.41 / 7.92,
6.28 / 7.72, 6.31 / 7.88 mJ (1.0: dress 6.71).

(``follow`` 0.5 and 0.75 with equal shares: ε_e / ε_a 3.47 / 4.02 and 3.60 / 4.05.) Keeping
part of each vertex's last frame-to-frame motion (a second-order follow, 0.9 of it with
loose_follow 0.2) keeps the hem moving for 0.37 s too (ε_e / ε_a 3.29 / 3.80), but lifts the
dress's and long skirt's inertia above LBS's (LBS ÷ ours 0.93 and 0.87).

    sim = Simulator.load([(garment, body)], checkpoint)   # or Simulator(module_a, [identity, ...])
    for rotations, root, body_vertices in motion_frames:  # (31,3,3), (3,), (Vb,3) per character
        vertices = sim.step(rotations[None], root[None], body_vertices[None])[0]   # (V,3)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from hyperbones.body.skeleton import forward_kinematics, skinning_transforms
from hyperbones.errors import InputFileError, ParameterError
from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.models.module_a import ModuleA, ModuleAConfig, bone_codes, correct_bones, heading_frame
from hyperbones.rig.virtual_bones import pose_bones
from hyperbones.runtime.identity import Identity
from hyperbones.runtime.isometry import ITERATIONS as PROJECTION_ITERATIONS
from hyperbones.runtime.isometry import EdgeProjection

FOLLOW = 0.6  # the share of the way to Module A's output the garment goes each frame (1: none)
LOOSE_FOLLOW = 0.4  # the same for loose cloth (FOLLOW_FAR or more from the skin): it lags and settles later
CARRY_LAG = 0.5  # the share of the character's last-but-one frame-to-frame motion in what carries loose cloth
FOLLOW_NEAR, FOLLOW_FAR = 0.01, 0.04  # m from the skin: cloth nearer is carried by the skin, farther by the character

if TYPE_CHECKING:
    from hyperbones.body.anny_body import Body
    from hyperbones.garment.garment import Garment



def transform_points(transform: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """(...,4,4) affine maps, (...,P,3) points -> (...,P,3) (each map applied to its P points)."""
    return points @ transform[..., :3, :3].transpose(-1, -2) + transform[..., None, :3, 3]


def hyperbones_payload(path=None, device: str | torch.device = "cpu") -> dict:
    """A HyperBones checkpoint's payload (default: the shipped model), refusing a teacher's."""
    from hyperbones.training.checkpoint import SHIPPED_HYPERBONES, load_checkpoint

    if path is None:
        if not SHIPPED_HYPERBONES.exists():
            raise ParameterError("no trained HyperBones model ships with this version yet: train one with "
                                 "`hyperbones train --config configs/hyperbones-small.toml` and pass --checkpoint FILE")
        path = SHIPPED_HYPERBONES
    payload = load_checkpoint(path, map_location=device)
    if "runtime" not in payload["config"]:
        raise InputFileError(path, "a teacher checkpoint, not a HyperBones one (its config has no [runtime] table)")
    return payload


def hyperbones_from_checkpoint(path=None, device: str | torch.device = "cpu"):
    """The ``HyperBonesModel`` (eval mode) of a joint training checkpoint or an exported one
    (default: the shipped one). Building it imports the teacher (Warp); ``load_module_a``
    is the light path for Module A alone."""
    from hyperbones.models.hyperbones import HyperBonesModel

    return HyperBonesModel.from_payload(hyperbones_payload(path, device)).to(device)


def load_module_a(path=None, device: str | torch.device = "cpu") -> ModuleA:
    """Module A alone from a HyperBones checkpoint (all the per-frame runtime needs with
    identity caches; no teacher, Warp or Anny), in eval mode."""
    payload = hyperbones_payload(path, device)
    module = ModuleA(ModuleAConfig.from_dict(payload["config"]["runtime"]))
    state = payload.get("ema") or payload["model"]
    module.load_state_dict({name[len("runtime."):]: value for name, value in state.items()
                            if name.startswith("runtime.")})
    return module.to(device).eval()


@dataclass
class IdentityBatch:
    """N identity caches (one per character; the same one may repeat) with the inputs the
    Bone-Net and the Conv-MLP take from them stacked once, not every frame.

    film: (N,layers,2,hidden); features_uv: (N,d_f,R,R); coverage: (N,1,R,R);
    codes: (N,B,C) the per-bone Bone-Net's bone codes (``module_a.bone_codes``).
    """

    identities: list[Identity]
    film: torch.Tensor
    features_uv: torch.Tensor
    coverage: torch.Tensor
    codes: torch.Tensor

    @classmethod
    def of(cls, identities: list[Identity]) -> "IdentityBatch":
        codes = [bone_codes(identity.bones.joint_weights, identity.bones.rest_positions,
                            identity.rest_joint_positions[0], identity.vertex_features, identity.bones.garment_vertex)
                 for identity in identities]
        return cls(identities, torch.stack([identity.film for identity in identities]),
                   torch.stack([identity.features_uv for identity in identities]),
                   torch.stack([identity.raster.coverage for identity in identities])[:, None], torch.stack(codes))


def module_a_frame(module_a: ModuleA, batch: IdentityBatch, window: torch.Tensor, rotations: torch.Tensor,
                   positions: torch.Tensor, to_local: torch.Tensor) -> list[torch.Tensor]:
    """One frame of Module A for N characters (differentiable; the trainer calls it too).

    Args:
        batch: the N characters' identities.
        window: (N,K,B,3) world bone positions at t−K+1 … t (K: ``module_a.config.window_frames``).
        rotations, positions: (N,B,3,3), (N,B,3) world bone frames at t.
        to_local: (N,4,4) world -> local frame of each character at t.

    Returns:
        N tensors (V_i,3): world garment positions at t.
    """
    identities = batch.identities
    local_window = transform_points(to_local[:, None], window)
    delta, pose_embedding = module_a.bone_corrections(local_window, batch.codes, batch.film)
    local_rotations = to_local[:, None, :3, :3] @ rotations
    local_positions = transform_points(to_local, positions)
    local_rotations, local_positions = correct_bones(local_rotations, local_positions, delta)
    stage_one = [
        linear_blend_skinning(identity.rest_vertices, identity.weights,
                              skinning_transforms(identity.bones.rest_positions, local_rotations[i:i + 1],
                                                  local_positions[i:i + 1]))[0]
        for i, identity in enumerate(identities)]
    if module_a.refiner is not None:
        images = torch.cat([identity.raster.rasterize(points[None]) for identity, points in zip(identities, stage_one)])
        displacement = module_a.refine(images, batch.coverage, batch.features_uv, pose_embedding)
        stage_one = [points + identity.raster.sample(displacement[i:i + 1])[0]
                     for i, (identity, points) in enumerate(zip(identities, stage_one))]
    to_world = torch.linalg.inv(to_local)
    return [transform_points(to_world[i], points) for i, points in enumerate(stage_one)]


class Simulator:
    """Module A stepping N characters frame by frame; it keeps their bone windows itself.

    identities: one cache per character (``encode_identity`` or ``Identity.load``), all at one
    UV resolution (the Conv-MLP is fully convolutional: it runs at the resolution the caches
    were made at, which need not be the one it was trained at).
    The first frame fills the window (the characters start at rest).
    """

    def __init__(self, module_a: ModuleA, identities: list[Identity], device: str | torch.device = "cpu",
                 body_faces: torch.Tensor | None = None, projection_iterations: int = PROJECTION_ITERATIONS,
                 follow: float = FOLLOW, loose_follow: float = LOOSE_FOLLOW, carry_lag: float = CARRY_LAG):
        """body_faces: (F,3) the characters' body triangles (one topology, as Anny's); with
        them ``step`` can take the posed bodies and resolve contact, then pull the garment's
        edges towards their rest lengths with ``projection_iterations`` per contact round (0:
        contact only). ``follow``, ``loose_follow`` in (0, 1] and ``carry_lag`` in [0, 1): see
        the module's docstring (both shares 1: Module A's output as it is)."""
        if not identities:
            raise ParameterError("Simulator needs at least one identity")
        for name, share in (("follow", follow), ("loose_follow", loose_follow)):
            if not 0.0 < share <= 1.0:
                raise ParameterError(f"{name} must be in (0, 1], got {share}")
        if not 0.0 <= carry_lag < 1.0:
            raise ParameterError(f"carry_lag must be in [0, 1), got {carry_lag}")
        bones = {identity.bones.num_bones for identity in identities}
        if bones != {module_a.config.num_bones}:
            raise ParameterError(f"identities have {sorted(bones)} virtual bones, the model expects "
                                 f"{module_a.config.num_bones}")
        resolutions = {identity.raster.resolution for identity in identities}
        if len(resolutions) > 1:
            raise ParameterError(f"identities stepped together need one UV resolution, got {sorted(resolutions)}")
        self.device = torch.device(device)
        self.module_a = module_a.to(self.device).eval()
        self.identities = [identity.to(self.device) for identity in identities]
        self.batch = IdentityBatch.of(self.identities)
        # The skeleton -> bones stage of every character, stacked, on the CPU.
        self.rest_joints = torch.stack([identity.rest_joint_positions.cpu() for identity in identities])  # (N,31,3)
        self.bone_joint_weights = torch.stack([identity.bones.joint_weights.cpu() for identity in identities])
        self.bone_rest = torch.stack([identity.bones.rest_positions.cpu() for identity in identities])  # (N,B,3)
        self.window: torch.Tensor | None = None  # (N,K,B,3) world bone positions
        self.follow, self.loose_follow, self.carry_lag = follow, loose_follow, carry_lag
        self.follows = follow < 1.0 or loose_follow < 1.0
        self.last_output: list[torch.Tensor] | None = None  # N (V_i,3): the last output (world)
        self.last_to_local: torch.Tensor | None = None  # (N,4,4): its frame's world -> heading frame
        self.last_motion: torch.Tensor | None = None  # (N,4,4): the heading frames' world motion into it
        self.contact = None
        if body_faces is not None:
            from hyperbones.runtime.contact import BodyContact

            projections = None
            if projection_iterations > 0:
                projections = [EdgeProjection(identity.rest_vertices, identity.faces, projection_iterations)
                               for identity in self.identities]
            self.contact = BodyContact(body_faces, len(identities), self.device, projections=projections)

    @classmethod
    def load(cls, characters: list[tuple[Garment, Body]], checkpoint=None, device: str | torch.device = "cpu",
             uv_resolution: int | None = None, contact: bool = True,
             projection_iterations: int = PROJECTION_ITERATIONS, follow: float = FOLLOW,
             loose_follow: float = LOOSE_FOLLOW, carry_lag: float = CARRY_LAG,
             rest_vertices: list[torch.Tensor | None] | None = None) -> "Simulator":
        """A simulator for (garment, body) pairs, each garment fitted to its body's canonical
        pose: Module B encodes every pair once with the model of ``checkpoint`` (default: the
        shipped one). ``contact``: ``step`` may then take the posed bodies (all characters
        share Anny's topology). ``rest_vertices``: each garment's rest shape (V_i,3), as
        ``draped_garment`` returns it, where its bones bind (``VirtualBones.bind``)."""
        from hyperbones.runtime.identity import encode_identity

        model = hyperbones_from_checkpoint(checkpoint, device)
        with torch.no_grad():
            rests = rest_vertices or [None] * len(characters)
            if len(rests) != len(characters):
                raise ParameterError(f"{len(rests)} rest shapes for {len(characters)} characters")
            identities = [encode_identity(model, garment, body, uv_resolution=uv_resolution, rest_vertices=rest)
                          for (garment, body), rest in zip(characters, rests)]
        return cls(model.runtime, identities, device, body_faces=characters[0][1].faces if contact else None,
                   projection_iterations=projection_iterations, follow=follow,
                   loose_follow=loose_follow, carry_lag=carry_lag)

    def _carried(self, character: int, motion: torch.Tensor,
                 body: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(V,3) world positions of ``character``'s last output carried to this frame (see the
        module's docstring) and (V,) how much each is carried by the skin (1: all, 0: none; None
        without a body); motion: (4,4) the world transform that carries loose cloth; body: (Vb,3) or None."""
        carried = transform_points(motion, self.last_output[character])
        skin = self.contact.skin_motion(character, body) if body is not None else None
        if skin is None:
            return carried, None
        moved, distance = skin
        on_skin = 1.0 - ((distance - FOLLOW_NEAR) / (FOLLOW_FAR - FOLLOW_NEAR)).clamp(0.0, 1.0)  # (V,)
        return carried + on_skin[:, None] * (self.last_output[character] + moved - carried), on_skin

    def reset(self) -> None:
        """Forget the motion so far (the next step starts at rest)."""
        self.window = None
        self.last_output = self.last_to_local = self.last_motion = None
        if self.contact is not None:
            self.contact.forget()

    @torch.no_grad()
    def step(self, joint_rotations: torch.Tensor, root_translation: torch.Tensor,
             body_vertices: torch.Tensor | None = None) -> list[torch.Tensor]:
        """One frame: (N,31,3,3) world joint rotations (relative to the A-pose), (N,3) Hips
        positions -> N tensors (V_i,3) of world garment positions. ``body_vertices`` (N,Vb,3):
        the posed bodies at this frame; garment vertices inside them are pushed out (needs
        ``body_faces``)."""
        count = len(self.identities)
        if body_vertices is not None and self.contact is None:
            raise ParameterError("step got posed bodies, but the Simulator was made without body_faces "
                                 "(Simulator.load(..., contact=True))")
        if joint_rotations.shape != (count, 31, 3, 3) or root_translation.shape != (count, 3):
            raise ParameterError(f"step expects ({count},31,3,3) rotations and ({count},3) roots, got "
                                 f"{tuple(joint_rotations.shape)} and {tuple(root_translation.shape)}")
        rotations_in = joint_rotations.detach().to("cpu", torch.float32)
        roots = root_translation.detach().to("cpu", torch.float32)
        joints = forward_kinematics(self.rest_joints, rotations_in, roots)
        transforms = skinning_transforms(self.rest_joints, rotations_in, joints)  # (N,31,4,4)
        rotations, positions = pose_bones(self.bone_joint_weights, self.bone_rest, transforms)
        to_local = heading_frame(rotations_in[:, 0], roots).to(self.device)
        rotations, positions = rotations.to(self.device), positions.to(self.device)
        if self.window is None:
            frames = self.module_a.config.window_frames
            self.window = positions[:, None].expand(count, frames, *positions.shape[1:]).clone()
        else:
            self.window = torch.cat([self.window[:, 1:], positions[:, None]], dim=1)
        garments = module_a_frame(self.module_a, self.batch, self.window, rotations, positions, to_local)
        bodies = body_vertices.to(self.device) if body_vertices is not None else None
        motion = None
        if self.follows and self.last_output is not None:
            motion = torch.linalg.inv(to_local) @ self.last_to_local  # (N,4,4) the heading frames' motion
            carrier = motion if self.last_motion is None else motion + self.carry_lag * (self.last_motion - motion)
            carried, on_skin = zip(*[self._carried(i, carrier[i], bodies[i] if bodies is not None else None)
                                     for i in range(count)])
            gap = self.follow - self.loose_follow
            shares = [self.follow if skin is None else self.loose_follow + gap * skin[:, None]
                      for skin in on_skin]  # N floats (no body) or (V_i,1)
            garments = [start + share * (target - start) for start, target, share in zip(carried, garments, shares)]
        if bodies is not None:
            garments = self.contact(garments, bodies)
        if self.follows:
            self.last_output, self.last_to_local, self.last_motion = garments, to_local, motion
        return garments
