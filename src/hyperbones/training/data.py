"""Training episodes for the teacher: a random body, garment, fabric and motion window.

Expensive parts are done once per process and reused by every episode:
  - each (template, resolution) is made on the default body (cached on disk like draped
    garments), with its LBS weights and a ``ShapeFollower`` that carries it to other shapes;
  - each clip is retargeted to the default body once, with a blend-in from the A-pose and
    a hold at the end.
Per episode a new body shape is cheap to make; the garment is carried onto it (that carried
garment is its rest shape) and the clip's root path is scaled by the leg-length ratio.
With ``data.drape`` the carried garment is also settled on the body (``draped_vertices``;
seconds to minutes each, cached on disk).
"""

from __future__ import annotations

import hashlib
import json
import random
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from hyperbones.body.anny_body import Body, body_for
from hyperbones.body.shape import BodyShape, draw_training_shape
from hyperbones.errors import InputFileError, ParameterError
from hyperbones.garment.drape import drape
from hyperbones.garment.draped import CACHE_VERSION as DRAPE_CACHE_VERSION
from hyperbones.garment.draped import cache_dir
from hyperbones.garment.garment import Garment
from hyperbones.garment.templates import make_template
from hyperbones.io_utils import atomic_path
from hyperbones.motion.load import load_motion
from hyperbones.motion.motion import Motion
from hyperbones.physics.material import Material
from hyperbones.rig.garment_skinning import garment_skin_weights
from hyperbones.training.config import DataConfig
from hyperbones.training.episode import Episode, EpisodeDraws, Identity, ballistic_hops
from hyperbones.training.shape_follower import ShapeFollower

TEMPLATE_CACHE_VERSION = 3


@dataclass
class GarmentSource:
    """A template made on the default body: the garment, its LBS weights (V,31), how it follows other shapes."""

    garment: Garment
    skin_weights: torch.Tensor
    follower: ShapeFollower


def template_source(name: str, vertices: int, default_body: Body) -> GarmentSource:
    """Make (or load from the cache) a template on the default body, with its weights and follower."""
    path = cache_dir() / "templates" / f"{name}-{vertices}-v{TEMPLATE_CACHE_VERSION}.pt"
    if path.exists():
        data = torch.load(path, weights_only=True)
        garment = Garment(data["vertices"], data["faces"], data["uvs"], data["face_uvs"], data["pinned"], name=name)
        weights = data["skin_weights"]
    else:
        garment = make_template(name, default_body, vertices)
        weights = garment_skin_weights(garment, default_body)
        with atomic_path(path) as tmp:
            torch.save({"vertices": garment.vertices, "faces": garment.faces, "uvs": garment.uvs,
                        "face_uvs": garment.face_uvs, "pinned": garment.pinned, "skin_weights": weights}, tmp)
    return GarmentSource(garment, weights, ShapeFollower.bind(garment, default_body))


def draped_vertices(garment: Garment, body: Body, resolution: int) -> torch.Tensor:
    """(V,3) ``garment`` (a template carried to ``body``, at ``resolution``) settled on the
    body's canonical pose by ``garment.drape``, its carried shape as rest shape; cached on
    disk by template, resolution, body shape and fabric.

    The solve starts from the carried garment. Starting it from the default body's drape
    carried to ``body`` was 1.7-3.6x faster for shirts and dresses but stalled on the long
    skirt and the trousers at 2,500 vertices (docs/experiments/2026-11-30-bank-draws-and-warm-drapes.md).
    """
    key = {"template": garment.name, "resolution": resolution, "body": body.shape.as_dict(),
           "material": garment.material.as_dict(), "templates": TEMPLATE_CACHE_VERSION, "drape": DRAPE_CACHE_VERSION}
    digest = hashlib.sha1(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    path = cache_dir() / "training-drapes" / f"{garment.name}-{resolution}-{digest}.pt"
    if path.exists():
        return torch.load(path, weights_only=True)
    with warnings.catch_warnings(), torch.enable_grad():  # the drape's Newton steps need gradients (rollouts run without)
        warnings.simplefilter("ignore")  # an unconverged drape is still a settled start; the rollout goes on from it
        settled, _ = drape(garment, body)
    with atomic_path(path) as tmp:
        torch.save(settled.vertices, tmp)
    return settled.vertices


class TeacherData(EpisodeDraws):
    """Samples episodes for training (``split="train"``) from the config's garments and motions."""

    def __init__(self, config: DataConfig, seed: int = 0, progress=None):
        self.config = config
        self.random = random.Random(seed)
        self.default_body = body_for(BodyShape())
        self.sources = {}
        for name in config.templates:
            for vertices in config.resolutions:
                if progress:
                    progress(f"garment {name} ({vertices} vertices)")
                self.sources[(name, vertices)] = template_source(name, vertices, self.default_body)
        self.motions: list[Motion] = []
        for clip in config.train_clips:
            path = Path(config.mocap_dir) / f"{clip}.bvh"
            if not path.exists():
                raise InputFileError(path, "training clip not found (set data.mocap_dir in the config)")
            if progress:
                progress(f"motion {clip}")
            self.motions.append(load_motion(str(path), self.default_body, hold=config.hold_seconds,
                                            source_fps=config.source_fps.get(clip)))
        for name in config.builtins:
            self.motions.append(load_motion(name, self.default_body, hold=config.hold_seconds))
        self.test_shapes = [BodyShape.parse(text) for text in config.test_bodies]

    def sample_shape(self) -> BodyShape:
        """A phenotype uniform over [0,1]^6, away from every held-out shape."""
        return draw_training_shape(self.random.random, self.test_shapes, self.config.test_body_margin)

    def sample_identity(self) -> Identity:
        name, vertices = self.random.choice(sorted(self.sources))
        return self.identity_for(name, vertices, self.sample_shape(), self.sample_material())

    def identity_for(self, name: str, vertices: int, shape: BodyShape, material: Material,
                     drape: bool | None = None, start: torch.Tensor | None = None) -> Identity:
        """Template ``name`` at resolution ``vertices`` (one of the config's) carried to the
        body of ``shape``, in ``material``, and draped there when ``drape`` (default: ``data.drape``).

        start: (V,3) the draped garment as a bank file saved it (then nothing is draped).
        """
        drape = self.config.drape if drape is None else drape
        if (name, vertices) not in self.sources:
            raise ParameterError(f"no training garment {name!r} at {vertices} vertices in this config")
        source = self.sources[(name, vertices)]
        body = Body(shape)
        rest_vertices = source.follower.place(body)
        garment = replace(source.garment.with_vertices(rest_vertices), material=material)
        if start is not None:
            if start.shape != rest_vertices.shape:
                raise ParameterError(f"a draped start of {tuple(start.shape)} for {name} at {vertices}, whose "
                                     f"garment here is {tuple(rest_vertices.shape)}")
            garment, drape = garment.with_vertices(start.float()), True
        elif drape:
            garment = garment.with_vertices(draped_vertices(garment, body, vertices))
        return Identity.build(name, body, rest_vertices, source.garment.faces, source.garment.pinned,
                              source.skin_weights, material, garment, vertices, drape)

    def sample_episode(self, steps: int, identity: Identity | None = None) -> Episode:
        """An episode of ``steps`` dynamic steps on ``identity`` (a new random one when None)."""
        identity = identity or self.sample_identity()
        window, root = self.sample_window(steps + 2, identity)
        if self.random.random() < self.config.airborne_fraction:
            root = root.clone()
            root[:, 2] += ballistic_hops(window.num_frames, window.fps, self.random, self.config.hop_speeds)
        posed = identity.body.pose(window.joint_rotations, root)
        return Episode(identity, posed.vertices, identity.skin(posed.skinning_transforms), window.name)
