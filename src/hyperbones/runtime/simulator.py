"""The per-frame runtime: Module A on cached identities, several characters per batch.

Per frame and character the cost is fixed: forward kinematics and the bones' skinning blend
(on the CPU for all characters at once), one Bone-Net pass and one Conv-MLP pass (batched over
characters), the garment skinning and two sparse products to and from the UV image. Module A
keeps only the last K frames of bone positions. Around it, each frame (``RuntimeConfig``):
the garment is carried from where the last frame left it (loose cloth with the character,
cloth on the skin with the skin) and goes a share of the way to Module A's output, which cuts
the jerks Module A copies from the skeleton; given the posed bodies, it is then pushed out of
them and its edges are pulled towards their rest lengths (``runtime.push_out``,
``runtime.edge_projection``): on a large garment this runs on its proxy, a coarse copy, and
the correction is spread over every vertex and finished there (``runtime.garment_proxy``,
``physics.strain_limit`` without its band). Measurements behind the defaults: ``docs/experiments/*runtime*.md``.

    sim = Simulator.load([(garment, body)], checkpoint)   # or Simulator(module_a, [identity, ...])
    for rotations, root, body_vertices in motion_frames:  # (31,3,3), (3,), (Vb,3) per character
        vertices = sim.step(rotations[None], root[None], body_vertices[None])[0]   # (V,3)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import torch

from hyperbones.body.skeleton import forward_kinematics, skinning_transforms
from hyperbones.devices import runs_bfloat16_natively
from hyperbones.errors import InputFileError, ParameterError
from hyperbones.geometry.lbs import linear_blend_skinning
from hyperbones.geometry.surface import found_points
from hyperbones.models.loading import SHIPPED_HYPERBONES, hyperbones_payload, load_checkpoint, model_of
from hyperbones.models.module_a import ModuleA, bone_codes, correct_bones, heading_frame
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.contact_planes import ContactPlanes
from hyperbones.physics.strain_limit import StrainLimiter
from hyperbones.rig.virtual_bones import pose_bones
from hyperbones.runtime.config import RuntimeConfig
from hyperbones.runtime.edge_projection import EdgeProjection
from hyperbones.runtime.identity import Identity
from hyperbones.runtime.stage_clock import NO_CLOCK

if TYPE_CHECKING:
    from hyperbones.body.anny_body import Body
    from hyperbones.garment.garment import Garment


def transform_points(transform: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """(...,4,4) affine maps, (...,P,3) points -> (...,P,3) (each map applied to its P points)."""
    return points @ transform[..., :3, :3].transpose(-1, -2) + transform[..., None, :3, 3]


def runtime_config_of(payload: dict, source: str | Path = "checkpoint") -> RuntimeConfig:
    """The runtime settings a HyperBones checkpoint (from ``source``) was exported with; one that
    stores none (a training checkpoint, an older export) runs with the shipped model's, so that
    it runs and measures as it would if shipped (``RuntimeConfig``'s bare defaults are another
    runtime: docs/experiments/2026-11-30-exported-runtime-settings.md). A stored one that is not
    a valid ``RuntimeConfig`` is an ``InputFileError`` naming ``source``."""
    stored = payload.get("runtime_config")
    if stored is None:
        return shipped_runtime_config()
    if not isinstance(stored, dict):
        raise InputFileError(source, f"its runtime_config is a {type(stored).__name__}, not a table of settings")
    try:
        return RuntimeConfig.from_dict(dict(stored), "runtime_config")
    except (ParameterError, TypeError) as error:
        raise InputFileError(source, f"bad runtime_config ({error})") from None


def runtime_config_in(path: str | Path) -> RuntimeConfig | None:
    """The runtime settings the model file ``path`` stores (None where it stores none: a training
    checkpoint, a teacher); a missing or bad file is an ``InputFileError`` naming it."""
    payload = load_checkpoint(path)
    return None if payload.get("runtime_config") is None else runtime_config_of(payload, path)


@functools.cache
def shipped_runtime_config() -> RuntimeConfig:
    """The runtime settings the shipped model stores (``RuntimeConfig()`` where the package holds
    no model, or one that stores none)."""
    if not SHIPPED_HYPERBONES.exists():
        return RuntimeConfig()
    return runtime_config_in(SHIPPED_HYPERBONES) or RuntimeConfig()


@dataclass
class IdentityBatch:
    """N identity caches (one per character; the same one may repeat) with the inputs the
    Bone-Net and the Conv-MLP take from them stacked once, not every frame.

    film: (N,layers,2,hidden); features_uv: (N,d_f,R,R); coverage: (N,1,R,R);
    codes: (N,B,C) the per-bone Bone-Net's bone codes (``module_a.bone_codes``);
    groups: the distinct identities, each with its rows (``grouped_rows``);
    group_rows: those rows as (n,) int64 tensors; order: (N,) each row's place when the
    groups' rows are laid one after another.
    """

    identities: list[Identity]
    film: torch.Tensor
    features_uv: torch.Tensor
    coverage: torch.Tensor
    codes: torch.Tensor
    groups: list[tuple[Identity, list[int]]]
    group_rows: list[torch.Tensor]
    order: torch.Tensor

    @classmethod
    def of(cls, identities: list[Identity]) -> "IdentityBatch":
        groups = grouped_rows(identities)
        codes = torch.stack([bone_codes(identity.bones.joint_weights, identity.bones.rest_positions,
                                        identity.rest_joint_positions[0], identity.vertex_features,
                                        identity.bones.garment_vertex) for identity, _ in groups])
        film = torch.stack([identity.film for identity, _ in groups])
        features_uv = torch.stack([identity.features_uv for identity, _ in groups])
        coverage = torch.stack([identity.raster.coverage for identity, _ in groups])[:, None]
        rows = [torch.tensor(group_rows, device=film.device) for _, group_rows in groups]
        group_of = torch.cat([torch.full_like(index, group) for group, index in enumerate(rows)])
        order = torch.cat(rows).argsort()
        group_of = group_of[order]  # (N,) each row's group
        return cls(identities, film[group_of], features_uv[group_of], coverage[group_of], codes[group_of], groups,
                   rows, order)


Item = TypeVar("Item")


def grouped_rows(items: list[Item]) -> list[tuple[Item, list[int]]]:
    """The distinct objects of a list (the same object repeated is one), in order of first
    appearance, each with the rows it fills: work per object (an identity of a crowd, a
    rollout of a training batch) then runs once per group."""
    groups: dict[int, tuple[Item, list[int]]] = {}
    for row, item in enumerate(items):
        groups.setdefault(id(item), (item, []))[1].append(row)
    return list(groups.values())


def pose_characters(rest_joints: torch.Tensor, bone_joint_weights: torch.Tensor, bone_rest: torch.Tensor,
                    joint_rotations: torch.Tensor, roots: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """N characters' skeletons to their virtual bones: (N,31,3) rest joints, (N,B,31) bone
    weights, (N,B,3) rest bone positions, (N,31,3,3) world joint rotations, (N,3) Hips
    positions -> (N,B,3,3) world bone rotations, (N,B,3) positions and (N,4,4) heading
    frames (world -> local)."""
    joints = forward_kinematics(rest_joints, joint_rotations, roots)
    transforms = skinning_transforms(rest_joints, joint_rotations, joints)  # (N,31,4,4)
    rotations, positions = pose_bones(bone_joint_weights, bone_rest, transforms)
    return rotations, positions, heading_frame(joint_rotations[:, 0], roots)


def module_a_frame(module_a: ModuleA, batch: IdentityBatch, window: torch.Tensor, rotations: torch.Tensor,
                   positions: torch.Tensor, to_local: torch.Tensor, clock=NO_CLOCK,
                   conv_mlp: bool = True, invert=torch.linalg.inv) -> list[torch.Tensor]:
    """One frame of Module A for N characters (differentiable; the trainer calls it too).

    Args:
        batch: the N characters' identities.
        window: (N,K,B,3) world bone positions at t−K+1 … t (K: ``module_a.config.window_frames``).
        rotations, positions: (N,B,3,3), (N,B,3) world bone frames at t.
        to_local: (N,4,4) world -> local frame of each character at t.
        clock: a ``StageClock`` to charge each stage's time to (none by default).
        conv_mlp: add the Conv-MLP's displacement (stage 2; ``RuntimeConfig.conv_mlp``).
        invert: (N,4,4) -> (N,4,4) inverse of the heading frames (an exported graph passes
            ``geometry.rotations.rigid_inverse``: ONNX has no matrix inverse).

    Returns:
        N tensors (V_i,3): world garment positions at t.
    """
    # Rows of one identity (a crowd of copies, a trainer's frames of one rollout) are skinned,
    # rasterised and sampled together: the work per step grows with the distinct identities.
    groups, rows = [identity for identity, _ in batch.groups], batch.group_rows
    with clock.stage("Bone-Net"):
        local_window = transform_points(to_local[:, None], window)
        delta, pose_embedding = module_a.bone_corrections(local_window, batch.codes, batch.film)
        local_rotations = to_local[:, None, :3, :3] @ rotations
        local_positions = transform_points(to_local, positions)
        local_rotations, local_positions = correct_bones(local_rotations, local_positions, delta)
    with clock.stage("garment skinning"):
        stage_one = [  # per group (n,V,3)
            linear_blend_skinning(identity.rest_vertices, identity.weights,
                                  skinning_transforms(identity.bones.rest_positions, local_rotations[index],
                                                      local_positions[index]))
            for identity, index in zip(groups, rows)]
    if module_a.refiner is not None and conv_mlp:
        with clock.stage("UV raster"):
            images = torch.cat([identity.raster.rasterize(points)
                                for identity, points in zip(groups, stage_one)])[batch.order]
        with clock.stage("Conv-MLP"):  # in the refiner's dtype and layout (``ModuleA.for_inference``)
            displacement = module_a.refine(images, batch.coverage, batch.features_uv, pose_embedding)
        with clock.stage("UV sampling"):
            stage_one = [points + identity.raster.sample(displacement[index])
                         for identity, points, index in zip(groups, stage_one, rows)]
    to_world = invert(to_local)
    garments: list[torch.Tensor | None] = [None] * len(batch.identities)
    for (_, group_rows), points, index in zip(batch.groups, stage_one, rows):
        for row, world in zip(group_rows, transform_points(to_world[index], points)):
            garments[row] = world
    return garments


class Simulator:
    """Module A stepping N characters frame by frame; it keeps their bone windows itself.

    identities: one cache per character (``encode_identity`` or ``Identity.load``), all at one
    UV resolution (the Conv-MLP is fully convolutional: it runs at the resolution the caches
    were made at, which need not be the one it was trained at), or remade at
    ``config.uv_resolution`` when that is set.
    The first frame fills the window (the characters start at rest).
    """

    def __init__(self, module_a: ModuleA, identities: list[Identity], device: str | torch.device = "cpu",
                 body_faces: torch.Tensor | None = None, config: RuntimeConfig = RuntimeConfig(),
                 search: str = "auto"):
        """body_faces: (F,3) the characters' body triangles (one topology, as Anny's); with
        them and ``config.contact``, ``step`` can take the posed bodies and resolve contact.
        config: every setting of the follow, contact and projection steps; search: the
        nearest-face search, "warp", "torch" or "auto" (``geometry.search.search_backend``:
        the answers are the same, only where it runs and its speed differ)."""
        if not identities:
            raise ParameterError("Simulator needs at least one identity")
        if not isinstance(config, RuntimeConfig):
            raise ParameterError(f"Simulator needs a RuntimeConfig, got {type(config).__name__}")
        bones = {identity.bones.num_bones for identity in identities}
        if bones != {module_a.config.num_bones}:
            raise ParameterError(f"identities have {sorted(bones)} virtual bones, the model expects "
                                 f"{module_a.config.num_bones}")
        if config.uv_resolution:
            remade = {id(identity): identity.at_resolution(config.uv_resolution) for identity in identities}
            identities = [remade[id(identity)] for identity in identities]  # a repeated one stays one object
        if body_faces is not None and config.contact:  # a proxy only where contact corrects the garment
            remade = {id(identity): identity.with_proxy(config.proxy_vertices) for identity in identities}
            identities = [remade[id(identity)] for identity in identities]
        resolutions = {identity.raster.resolution for identity in identities}
        if len(resolutions) > 1:
            raise ParameterError(f"identities stepped together need one UV resolution, got {sorted(resolutions)}")
        self.device = torch.device(device)
        # The Conv-MLP's dtype: bfloat16 as config.bfloat16 asks, but only where this device runs it
        # natively (emulated, it is several times slower than float32).
        bfloat16 = config.bfloat16 and runs_bfloat16_natively(self.device)
        self.conv_mlp_dtype = torch.bfloat16 if bfloat16 else torch.float32
        self.module_a = module_a.for_inference(self.device, bfloat16)
        self.identities = [identity.to(self.device) for identity in identities]
        self.batch = IdentityBatch.of(self.identities)
        # The skeleton -> bones stage of every character, stacked, on the CPU.
        self.rest_joints = torch.stack([identity.rest_joint_positions.cpu() for identity in identities])  # (N,31,3)
        self.bone_joint_weights = torch.stack([identity.bones.joint_weights.cpu() for identity in identities])
        self.bone_rest = torch.stack([identity.bones.rest_positions.cpu() for identity in identities])  # (N,B,3)
        self.window: torch.Tensor | None = None  # (N,K,B,3) world bone positions
        self.config = config
        self.last_output: list[torch.Tensor] | None = None  # N (V_i,3): the last output (world)
        self.last_to_local: torch.Tensor | None = None  # (N,4,4): its frame's world -> heading frame
        self.last_motion: torch.Tensor | None = None  # (N,4,4): the heading frames' world motion into it
        self.contact = None
        self.clock = NO_CLOCK  # ``profile`` sets a StageClock
        # Per character: its garment's proxy (``Identity.proxy``) or None, and with one the
        # sweeps that finish the garment after the proxy's correction is spread on it.
        self.proxies = [identity.proxy for identity in self.identities]
        self.sweeps: list[StrainLimiter | None] = [None] * len(identities)
        if body_faces is not None and config.contact:
            from hyperbones.runtime.push_out import BodyContact

            projections = None
            if config.projection_iterations > 0:
                made: dict[int, EdgeProjection] = {}  # one factorisation per distinct identity of a crowd
                for source, identity in zip(identities, self.identities):
                    if id(source) not in made:
                        rest, faces = identity.rest_vertices, identity.faces
                        if identity.proxy is not None:  # the contact corrects the proxy's vertices
                            rest, faces = rest[identity.proxy.vertex], identity.proxy.faces
                        made[id(source)] = EdgeProjection(
                            rest, faces, config.projection_iterations,
                            config.projection_anchor, config.projection_stretch, config.projection_compression,
                            device=self.device)
                projections = [made[id(source)] for source in identities]
            self.contact = BodyContact(body_faces, len(identities), self.device, projections=projections,
                                       config=config, search=search)
            sweeps: dict[int, StrainLimiter] = {}
            for row, (source, identity) in enumerate(zip(identities, self.identities)):
                if identity.proxy is not None and config.proxy_sweeps > 0:
                    if id(source) not in sweeps:  # the strain limiter with no band, equal masses
                        rest = ClothRest.from_mesh(identity.rest_vertices.detach().cpu().double(), identity.faces.cpu())
                        count = identity.num_vertices
                        sweeps[id(source)] = StrainLimiter.build(
                            rest.edges, rest.edge_lengths, torch.ones(count), torch.zeros(count, dtype=torch.bool),
                            stretch=0.0, compression=0.0, iterations=config.proxy_sweeps,
                            relaxation=config.proxy_relaxation).to(self.device)
                    self.sweeps[row] = sweeps[id(source)]

    @classmethod
    def load(cls, characters: list[tuple[Garment, Body]], checkpoint=None, device: str | torch.device = "cpu",
             uv_resolution: int | None = None, config: RuntimeConfig | None = None,
             overrides: dict | None = None,
             rest_vertices: list[torch.Tensor | None] | None = None, search: str = "auto") -> "Simulator":
        """A simulator for (garment, body) pairs, each garment fitted to its body's canonical
        pose: Module B encodes every pair once with the model of ``checkpoint`` (default: the
        shipped one) at ``uv_resolution`` (default: ``config.uv_resolution``, else the model's).
        ``config``: the runtime's settings (default: the checkpoint's, else the
        defaults), with ``overrides`` ({setting: value}, ``runtime.config.parse_overrides``)
        applied; with ``config.contact``, ``step`` may take the posed bodies (all characters
        share Anny's topology). ``rest_vertices``: each garment's rest shape (V_i,3), as
        ``draped_garment`` returns it, where its bones bind (``VirtualBones.bind``); ``search``:
        the contact's nearest-face search (see the constructor)."""
        from hyperbones.runtime.identity import encode_identity

        payload = hyperbones_payload(checkpoint, device)
        model = model_of(payload, device)
        config = replace(config or runtime_config_of(payload, checkpoint or SHIPPED_HYPERBONES), **(overrides or {}))
        if uv_resolution:  # the config says what ran
            config = replace(config, uv_resolution=uv_resolution)
        with torch.no_grad():
            rests = rest_vertices or [None] * len(characters)
            if len(rests) != len(characters):
                raise ParameterError(f"{len(rests)} rest shapes for {len(characters)} characters")
            resolution = config.uv_resolution or None
            identities = [encode_identity(model, garment, body, uv_resolution=resolution, rest_vertices=rest)
                          for (garment, body), rest in zip(characters, rests)]
        return cls(model.runtime, identities, device, body_faces=characters[0][1].faces, config=config,
                   search=search)

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
        proxy = self.proxies[character]
        if proxy is not None:  # the contact's records are the proxy's: each vertex reads its main corner's
            main = proxy.main_corner
            moved, distance = moved[main], distance[main]
        near, far = self.config.follow_near, self.config.follow_far
        on_skin = 1.0 - ((distance - near) / (far - near)).clamp(0.0, 1.0)  # (V,)
        return carried + on_skin[:, None] * (self.last_output[character] + moved - carried), on_skin

    def profile(self, clock=NO_CLOCK) -> None:
        """Charge each stage of every later frame to ``clock`` (a ``StageClock``; ``NO_CLOCK``: stop)."""
        self.clock = clock
        if self.contact is not None:
            self.contact.clock = clock

    def reset(self) -> None:
        """Forget the motion so far (the next step starts at rest)."""
        self.window = None
        self.last_output = self.last_to_local = self.last_motion = None
        if self.contact is not None:
            self.contact.forget()

    def _resolve_contact(self, garments: list[torch.Tensor], bodies: torch.Tensor) -> list[torch.Tensor]:
        """N garments (V_i,3) and the (N,Vb,3) posed bodies -> the garments after contact. A
        garment with a proxy: the contact corrects the proxy's vertices, the correction is spread
        over the garment by the proxy's weights, edge sweeps over the whole garment remove the
        stretch left between the proxy's vertices (its skin planes kept), and the vertices near
        the skin are searched and pushed out."""
        proxies = self.proxies
        inputs = [garment if proxy is None else garment[proxy.vertex] for garment, proxy in zip(garments, proxies)]
        corrected = self.contact(inputs, bodies)
        out = []
        for character, (garment, before, after, proxy) in enumerate(zip(garments, inputs, corrected, proxies)):
            if proxy is None:
                out.append(after)
                continue
            nearest, main = self.contact.last_nearest[character], proxy.main_corner
            with self.clock.stage("proxy sweeps"):
                garment = garment + proxy.spread(after - before)
                if self.sweeps[character] is not None:  # each vertex held by its main corner's skin plane
                    held = (nearest.found[main] & (nearest.signed_distance[main] < self.config.plane_reach)).nonzero()
                    vertex = held.squeeze(1)
                    normal = nearest.normal[main[vertex]]
                    planes = ContactPlanes(vertex, nearest.point[main[vertex]] + self.contact.margin * normal, normal)
                    garment = self.sweeps[character].project(garment, planes)
            with self.clock.stage("contact queries"):
                # Where the proxy's triangle says the skin is near: an exact search and push-out.
                distance = torch.where(nearest.found, nearest.signed_distance,
                                       torch.full_like(nearest.signed_distance, self.config.query_distance))
                near = (proxy.spread(distance[:, None])[:, 0] < self.config.proxy_push_reach).nonzero().squeeze(1)
                garment = self.contact.push_out_rows(character, garment, near, found_points(nearest)[main[near]])
            out.append(garment)
        return out

    @torch.no_grad()
    def step(self, joint_rotations: torch.Tensor, root_translation: torch.Tensor,
             body_vertices: torch.Tensor | None = None) -> list[torch.Tensor]:
        """One frame: (N,31,3,3) world joint rotations (relative to the A-pose), (N,3) Hips
        positions -> N tensors (V_i,3) of world garment positions. ``body_vertices`` (N,Vb,3):
        the posed bodies at this frame; garment vertices inside them are pushed out (needs
        ``body_faces``)."""
        count = len(self.identities)
        if body_vertices is not None and self.contact is None:
            raise ParameterError("step got posed bodies, but the Simulator resolves no contact (made without "
                                 "body_faces, or with config.contact false)")
        if joint_rotations.shape != (count, 31, 3, 3) or root_translation.shape != (count, 3):
            raise ParameterError(f"step expects ({count},31,3,3) rotations and ({count},3) roots, got "
                                 f"{tuple(joint_rotations.shape)} and {tuple(root_translation.shape)}")
        clock = self.clock
        with clock.stage("forward kinematics"):
            rotations_in = joint_rotations.detach().to("cpu", torch.float32)
            roots = root_translation.detach().to("cpu", torch.float32)
            rotations, positions, to_local = pose_characters(self.rest_joints, self.bone_joint_weights,
                                                             self.bone_rest, rotations_in, roots)
            rotations, positions, to_local = (tensor.to(self.device) for tensor in (rotations, positions, to_local))
        if self.window is None:
            frames = self.module_a.config.window_frames
            self.window = positions[:, None].expand(count, frames, *positions.shape[1:]).clone()
        else:
            self.window = torch.cat([self.window[:, 1:], positions[:, None]], dim=1)
        garments = module_a_frame(self.module_a, self.batch, self.window, rotations, positions, to_local, clock,
                                  self.config.conv_mlp)
        bodies = body_vertices.to(self.device) if body_vertices is not None else None
        motion = None
        settings = self.config
        if settings.follows and self.last_output is not None:
            with clock.stage("follow"):
                motion = torch.linalg.inv(to_local) @ self.last_to_local  # (N,4,4) the heading frames' motion
                carrier = (motion if self.last_motion is None
                           else motion + settings.carry_lag * (self.last_motion - motion))
                carried, on_skin = zip(*[self._carried(i, carrier[i], bodies[i] if bodies is not None else None)
                                         for i in range(count)])
                gap = settings.follow - settings.loose_follow
                shares = [settings.follow if skin is None else settings.loose_follow + gap * skin[:, None]
                          for skin in on_skin]  # N floats (no body) or (V_i,1)
                garments = [start + share * (target - start)
                            for start, target, share in zip(carried, garments, shares)]
        if bodies is not None:
            garments = self._resolve_contact(garments, bodies)
        if settings.follows:
            self.last_output, self.last_to_local, self.last_motion = garments, to_local, motion
        clock.frame()
        return garments
