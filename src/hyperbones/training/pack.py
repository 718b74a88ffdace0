"""``hyperbones pack``: everything training episodes take from Anny, Warp and the drape, in one file.

The project's GPU machines have torch but neither Anny, Warp nor potpourri3d, and take at
most 64 MiB with them. A pack holds what a training episode needs from those libraries, so
the torch-only trainer (``training.from_pack``) can run there:
  - the bodies: the default body and ``bodies`` training shapes drawn as ``TeacherData``
    draws them (away from the held-out bodies), as coefficients over a PCA basis of their
    rest meshes (Anny's shape space has rank ~120, so the basis is exact to micrometres and
    a body costs 0.5 kB), their rest joints and leg lengths, one face list and one skinning
    table (Anny's do not change with the shape);
  - each template of the config at each resolution, made on the default body: mesh, UVs,
    pins, LBS weights, the binding that carries it to another shape (``ShapeFollower``), and
    for a phase-2 config its virtual bones (farthest-point picks and geodesic distances, fp16);
  - every training clip and built-in motion retargeted to the default body (with the
    config's hold), as unit quaternions;
  - the fabric ranges episodes draw from.
The trainer checks that the config it runs has the data fields the pack was made from
(``PACKED_FIELDS``).
"""

from __future__ import annotations

import random
from dataclasses import asdict
from pathlib import Path

import torch

from hyperbones.errors import ParameterError
from hyperbones.io_utils import atomic_path
from hyperbones.training.config import HyperBonesTrainingConfig, TeacherTrainingConfig

PACK_VERSION = 1
PACKED_FIELDS = ("templates", "resolutions", "mocap_dir", "train_clips", "source_fps", "builtins", "test_bodies",
                 "validation_bodies", "test_body_margin", "hold_seconds", "drape")
"""``DataConfig`` fields a pack is made from; a run must have the same ones."""
BODY_TOLERANCE = 2e-5  # m: the most a packed body may differ from Anny's mesh (the PCA's rank is chosen by it)
DEFAULT_BODIES = 256
QUICK_DATA = ('data.templates=["tshirt"]', "data.resolutions=[1000]", 'data.train_clips=["01_01"]',
              'data.validation_clips=["01_01"]', 'data.builtins=["walk"]')
"""``--quick`` (``hyperbones pack`` and the pack trainer alike): one 1k-vertex template, one
clip and the walk, so a check runs in seconds; with ``QUICK_BODIES`` bodies."""
QUICK_BODIES = 2
SKIN_INFLUENCES = 8  # joints per body vertex kept (Anny's skinning has at most 7)


def pack_bones(config: TeacherTrainingConfig) -> int:
    """Virtual bones per template in a pack for ``config``: its Module A's for a phase-2
    config; none for a teacher's, which does not use them (their distances are a third of a pack)."""
    return config.runtime.num_bones if isinstance(config, HyperBonesTrainingConfig) else 0


def training_shapes(config: TeacherTrainingConfig, count: int, seed: int = 0) -> list:
    """``count`` distinct body shapes drawn uniformly over the phenotype cube, each at least
    ``data.test_body_margin`` from every test and validation body (``TeacherData.sample_shape``'s rule)."""
    from hyperbones.body.shape import BodyShape, draw_training_shape

    held_out = [BodyShape.parse(text) for text in (*config.data.test_bodies, *config.data.validation_bodies)]
    draw = random.Random(seed)
    return [draw_training_shape(draw.random, held_out, config.data.test_body_margin) for _ in range(count)]


def body_table(shapes: list, progress=None) -> dict[str, torch.Tensor]:
    """The pack's ``body`` entry for the default body (row 0) and ``shapes`` (rows 1…N)."""
    from hyperbones.body.anny_body import Body
    from hyperbones.body.shape import PHENOTYPE_KEYS, BodyShape

    bodies = []
    for index, shape in enumerate([BodyShape(), *shapes]):
        if progress and index % 64 == 0:
            progress(f"bodies {index}/{len(shapes) + 1}")
        bodies.append(Body(shape))
    meshes = torch.stack([body.rest_vertices for body in bodies]).double().reshape(len(bodies), -1)  # (N,Vb·3)
    mean = meshes.mean(0)
    _, values, directions = torch.linalg.svd(meshes - mean, full_matrices=False)
    rank = len(values)
    for rank in range(8, len(values) + 1, 8):  # the smallest basis that rebuilds every body within tolerance
        # (before the basis is quantised below, which adds a few micrometres)
        basis = directions[:rank]
        rebuilt = (meshes - mean) @ basis.T @ basis + mean
        if float((rebuilt - meshes).reshape(len(bodies), -1, 3).norm(dim=-1).max()) <= BODY_TOLERANCE:
            break
    basis = directions[:rank]
    coefficients = (meshes - mean) @ basis.T
    # int16 rows with a scale each: half of float32's bytes, ~1e-5 of a row's largest entry.
    scale = basis.abs().amax(1, keepdim=True) / 32767
    quantised = torch.round(basis / scale).to(torch.int16)
    stored = quantised.double() * scale.float().double()
    error = float(((coefficients.float().double() @ stored + mean.float().double()) - meshes)
                  .reshape(len(bodies), -1, 3).norm(dim=-1).max())
    weights = bodies[0].skin_weights.float()
    top = weights.topk(SKIN_INFLUENCES, dim=1)
    if float((weights.sum(1) - top.values.sum(1)).abs().max()) > 1e-6:
        raise ParameterError(f"the body's skinning has more than {SKIN_INFLUENCES} joints per vertex")
    return {
        "faces": bodies[0].faces.to(torch.int32),
        "skin_joints": top.indices.to(torch.uint8), "skin_values": top.values,
        "mean": mean.float().reshape(-1, 3),
        "basis": quantised, "basis_scale": scale.float(),
        "coefficients": coefficients.float(),
        "joints": torch.stack([body.rest_joint_positions for body in bodies]).float(),
        "leg_length": torch.tensor([body.leg_length for body in bodies], dtype=torch.float32),
        "shapes": torch.tensor([[getattr(body.shape, key) for key in PHENOTYPE_KEYS] for body in bodies],
                               dtype=torch.float32),
        "error_max": torch.tensor(error),
    }


def template_entry(name: str, vertices: int, default_body, num_bones: int) -> dict:
    """One template at one resolution on the default body: mesh, weights, carrying binding, bones."""
    from hyperbones.geometry.geodesic import geodesic_distances
    from hyperbones.geometry.sampling import farthest_point_sampling
    from hyperbones.training.data import template_source

    source = template_source(name, vertices, default_body)
    garment, follower = source.garment, source.follower
    if num_bones > garment.num_vertices:
        raise ParameterError(f"template {name} at {vertices} vertices has {garment.num_vertices} vertices, "
                             f"fewer than the {num_bones} virtual bones asked for")
    bones = {}
    if num_bones:
        picked = farthest_point_sampling(garment.vertices, num_bones)
        distance = geodesic_distances(garment.vertices, garment.faces, picked).T  # (V,B)
        bones = {"bone_vertex": picked.long(), "bone_distance": distance.half()}
    return {
        "name": name, "resolution": vertices,
        "vertices": garment.vertices.float(), "faces": garment.faces.to(torch.int32),
        "uvs": garment.uvs.float(), "face_uvs": garment.face_uvs.to(torch.int32), "pinned": garment.pinned.long(),
        "skin_weights": source.skin_weights.half(),  # renormalised on loading
        "follower": {"face": follower.face.to(torch.int32), "barycentric": follower.barycentric.float(),
                     "source_points": follower.source_points.float(), "edges": follower.edges.to(torch.int32),
                     "rate": follower.rate.float(), "steps": int(follower.steps)},
        **bones,
    }


def motion_entry(motion) -> dict:
    """A retargeted ``Motion`` as unit quaternions (T,31,4) and its root path (T,3)."""
    import roma

    return {"name": motion.name, "fps": float(motion.fps),
            "quaternions": roma.rotmat_to_unitquat(motion.joint_rotations.double()).float(),
            "root": motion.root_translation.float()}


def build_pack(config: TeacherTrainingConfig, out: str | Path, bodies: int = DEFAULT_BODIES, seed: int = 0,
               progress=None) -> dict:
    """Write the training pack of ``config`` to ``out`` (atomically); returns its summary
    (counts, the bodies' largest rebuild error, the file's size). Needs Anny, Warp and potpourri3d."""
    from hyperbones.body.anny_body import body_for
    from hyperbones.body.shape import BodyShape
    from hyperbones.errors import InputFileError
    from hyperbones.motion.load import load_motion
    from hyperbones.physics.material import TRAINING_RANGES, Material

    if bodies < 1:
        raise ParameterError(f"--bodies must be at least 1, got {bodies}")
    data = config.data
    say = progress or (lambda text: None)
    default_body = body_for(BodyShape())
    num_bones = pack_bones(config)
    templates = []
    for name in data.templates:
        for vertices in data.resolutions:
            say(f"template {name} ({vertices} vertices)")
            templates.append(template_entry(name, vertices, default_body, num_bones))
    motions = []
    for clip in data.train_clips:
        path = Path(data.mocap_dir) / f"{clip}.bvh"
        if not path.exists():
            raise InputFileError(path, "training clip not found (set data.mocap_dir in the config)")
        say(f"motion {clip}")
        motions.append(motion_entry(load_motion(str(path), default_body, hold=data.hold_seconds,
                                                source_fps=data.source_fps.get(clip))))
    for name in data.builtins:
        motions.append(motion_entry(load_motion(name, default_body, hold=data.hold_seconds)))
    body = body_table(training_shapes(config, bodies, seed), say)
    payload = {"version": PACK_VERSION, "data": asdict(data), "num_bones": num_bones, "seed": seed,
               "body": body, "templates": templates, "motions": motions,
               "materials": {"ranges": {k: list(v) for k, v in TRAINING_RANGES.items()},
                             "default": Material().as_dict()}}
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        torch.save(payload, tmp)
    return {"bodies": bodies, "basis": int(body["basis"].shape[0]), "body_error_m": float(body["error_max"]),
            "templates": len(templates), "motions": len(motions),
            "frames": sum(int(m["root"].shape[0]) for m in motions), "bytes": out.stat().st_size}


__all__ = ["PACK_VERSION", "PACKED_FIELDS", "QUICK_BODIES", "QUICK_DATA", "build_pack", "training_shapes"]
