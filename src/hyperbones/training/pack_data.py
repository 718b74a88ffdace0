"""A training pack loaded, and episodes drawn from it: ``TeacherData``'s job in torch alone.

``PackData`` samples as ``TeacherData`` does (a random training body, template, resolution,
fabric and clip window, the root path scaled to the body's legs, optional free-fall hops),
but every body, garment and motion comes out of a pack written by ``hyperbones pack``
(``training.pack``), so it runs where Anny, Warp and potpourri3d are not installed.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from hyperbones.body.rig import BodyRig
from hyperbones.body.skeleton import NUM_JOINTS
from hyperbones.errors import InputFileError, ParameterError
from hyperbones.garment.garment import Garment
from hyperbones.io_utils import load_versioned
from hyperbones.physics.material import Material
from hyperbones.training.config import DataConfig
from hyperbones.training.episode import Episode, EpisodeDraws, Identity, ballistic_hops
from hyperbones.training.pack import PACK_VERSION, PACKED_FIELDS
from hyperbones.training.shape_follower import ShapeFollower


@dataclass
class PackBody(BodyRig):
    """A body of the pack: its rig, its row in the pack (0: the default body) and leg length (m)."""

    row: int = 0
    leg_length: float = 1.0


@dataclass
class PackTemplate:
    """One template at one resolution, made on the default body.

    garment: mesh, UVs and pins in HOOD's default fabric; skin_weights: (V,31);
    follower: carries it to another body; bone_vertex: (B,) the virtual bones' vertices;
    bone_distance: (V,B) geodesic distances to them (fp16, inf across separate pieces) on
    the default body (a phase-2 pack's; None in a teacher's).
    """

    garment: Garment
    resolution: int
    skin_weights: torch.Tensor
    follower: ShapeFollower
    bone_vertex: torch.Tensor | None = None
    bone_distance: torch.Tensor | None = None


@dataclass
class PackMotion:
    """A retargeted motion: joint_rotations (T,31,3,3), root_translation (T,3) on the default body."""

    name: str
    fps: float
    joint_rotations: torch.Tensor
    root_translation: torch.Tensor

    @property
    def num_frames(self) -> int:
        return self.root_translation.shape[0]

    def slice(self, start: int, stop: int) -> "PackMotion":
        return PackMotion(f"{self.name}[{start}:{stop}]", self.fps, self.joint_rotations[start:stop],
                          self.root_translation[start:stop])


class TrainingPack:
    """A pack file in memory (CPU tensors): bodies, templates, motions, fabric ranges."""

    def __init__(self, path: str | Path):
        import roma

        self.path = Path(path)
        payload = load_versioned(self.path, "training pack", PACK_VERSION)
        try:
            self.data = payload["data"]
            self.num_bones = int(payload["num_bones"])
            body = payload["body"]
            self.body_faces = body["faces"].long()
            joints, values = body["skin_joints"].long(), body["skin_values"].float()
            self.skin_weights = torch.zeros(joints.shape[0], NUM_JOINTS).scatter_add_(1, joints, values)
            self.mean = body["mean"].float()
            self.basis = body["basis"].float() * body["basis_scale"].float()  # (K,Vb·3) from int16 rows
            self.coefficients, self.joints = body["coefficients"].float(), body["joints"].float()
            self.leg_lengths = body["leg_length"].float()
            self.templates = {(entry["name"], int(entry["resolution"])): self._template(entry)
                              for entry in payload["templates"]}
            self.motions = [PackMotion(entry["name"], float(entry["fps"]),
                                       roma.unitquat_to_rotmat(entry["quaternions"].float()), entry["root"].float())
                            for entry in payload["motions"]]
        except (KeyError, TypeError, AttributeError) as error:
            raise InputFileError(self.path, f"damaged training pack ({type(error).__name__}: {error})") from None
        rows = self.coefficients.shape[0]
        if (rows < 2 or self.basis.shape[1] != self.mean.numel() or self.joints.shape[0] != rows
                or self.leg_lengths.shape[0] != rows or not self.motions or not self.templates):
            raise InputFileError(self.path, "damaged training pack: its tables do not fit together")

    @staticmethod
    def _template(entry: dict) -> PackTemplate:
        faces = entry["faces"].long()
        garment = Garment(entry["vertices"].float(), faces, entry["uvs"].float(), entry["face_uvs"].long(),
                          entry["pinned"].long(), name=entry["name"])
        bound = entry["follower"]
        follower = ShapeFollower(garment.vertices, bound["face"].long(), bound["barycentric"].float(),
                                 bound["source_points"].float(), bound["edges"].long(), bound["rate"].float(),
                                 int(bound["steps"]))
        weights = entry["skin_weights"].float()  # stored in float16
        weights = weights / weights.sum(1, keepdim=True)
        bones = entry.get("bone_vertex")
        return PackTemplate(garment, int(entry["resolution"]), weights, follower,
                            None if bones is None else bones.long(), entry.get("bone_distance"))

    @property
    def num_bodies(self) -> int:
        """Training bodies (rows 1…N; row 0 is the default body)."""
        return self.coefficients.shape[0] - 1

    def body(self, row: int) -> PackBody:
        """The body of pack row ``row`` (0: the default body), rebuilt from the PCA basis."""
        vertices = (self.mean.reshape(-1) + self.coefficients[row] @ self.basis).reshape(-1, 3)
        return PackBody(f"pack body {row}", vertices, self.body_faces, self.skin_weights, self.joints[row],
                        row=row, leg_length=float(self.leg_lengths[row]))

    def check(self, config: DataConfig) -> None:
        """Raise unless ``config`` has the data fields this pack was made from."""
        from dataclasses import asdict

        mine = asdict(config)
        differ = [name for name in PACKED_FIELDS if _plain(mine[name]) != _plain(self.data.get(name))]
        if differ:
            raise ParameterError(f"{self.path}: the pack was made for other data.{', data.'.join(differ)} "
                                 f"than this config's (make it again with hyperbones pack)")


def _plain(value):
    """Tuples as lists, so a config's fields compare with a pack's saved ones."""
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    return value


class PackData(EpisodeDraws):
    """Samples training episodes from a pack (``TeacherData``'s interface): bodies, garments,
    fabrics and motions drawn by ``seed``; bodies are posed on ``device``."""

    def __init__(self, pack: TrainingPack, config: DataConfig, seed: int = 0, device: str | torch.device = "cpu"):
        pack.check(config)
        self.pack, self.config = pack, config
        self.random = random.Random(seed)
        self.device = torch.device(device)
        self.default_body = pack.body(0)
        self.sources = pack.templates
        self.motions = pack.motions

    def sample_identity(self) -> Identity:
        name, vertices = self.random.choice(sorted(self.sources))
        return self.identity_for(name, vertices, self.random.randint(1, self.pack.num_bodies), self.sample_material())

    def identity_for(self, name: str, vertices: int, row: int, material: Material) -> Identity:
        """Template ``name`` at ``vertices`` carried to pack body ``row`` in ``material`` (on the CPU)."""
        if (name, vertices) not in self.sources:
            raise ParameterError(f"{self.pack.path}: no garment {name!r} at {vertices} vertices in this pack")
        source = self.sources[(name, vertices)]
        body = self.pack.body(row)
        rest_vertices = source.follower.place(body)
        garment = replace(source.garment.with_vertices(rest_vertices), material=material)
        return Identity.build(name, body, rest_vertices, garment.faces, garment.pinned, source.skin_weights,
                              material, garment, vertices, False)

    def pose(self, identity: Identity, joint_rotations: torch.Tensor, root: torch.Tensor
             ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``identity``'s body along (T,31,3,3) rotations and a (T,3) root path, on ``device``:
        (T,Vb,3) its vertices, (T,31,4,4) skinning transforms and (T,V,3) the garment by LBS."""
        vertices, transforms = identity.body.to(self.device).posed(joint_rotations.to(self.device),
                                                                   root.to(self.device))
        return vertices, transforms, identity.skin(transforms)

    def sample_episode(self, steps: int, identity: Identity | None = None) -> Episode:
        """An episode of ``steps`` dynamic steps on ``identity`` (a new random one when None),
        its body and skinned garment on ``device``."""
        identity = identity or self.sample_identity()
        window, root = self.sample_window(steps + 2, identity)
        if self.random.random() < self.config.airborne_fraction:
            root = root.clone()
            root[:, 2] += ballistic_hops(window.num_frames, window.fps, self.random, self.config.hop_speeds)
        vertices, _, garment_lbs = self.pose(identity, window.joint_rotations, root)
        return Episode(identity, vertices, garment_lbs, window.name)


__all__ = ["PackData", "PackMotion", "PackTemplate", "TrainingPack"]
