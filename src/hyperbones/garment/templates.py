"""Procedural garments fitted to any Anny body: the project's default garments.

Each template starts as a solid: the body grown by an ease (from its signed distance),
united for skirts with a flared hull around both legs. Marching cubes gives its surface,
which planes then cut open exactly (hem, waist, neckline, sleeve ends: a sleeve's plane
cuts only the faces over the arm). The surface is remeshed isotropically to the
requested vertex count and given a UV atlas (xatlas). Skirts, dresses and pants get a
pinnable waistband.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from hyperbones.body.anny_body import Body
from hyperbones.body.skeleton import JOINT_INDEX as J
from hyperbones.body.skeleton import JOINT_NAMES, JOINT_PARENTS
from hyperbones.errors import ParameterError
from hyperbones.garment.garment import Garment
from hyperbones.garment.surface import isotropic_remesh, largest_piece, slice_mesh, surface_from_field, uv_atlas

def _ancestors(joint: int) -> list[int]:
    """The joint itself and every joint above it."""
    chain = [joint]
    while JOINT_PARENTS[chain[-1]] >= 0:
        chain.append(JOINT_PARENTS[chain[-1]])
    return chain


DEFAULT_VERTICES = 5000
SKIRT_TAPER = 0.08
MIN_VERTICES, MAX_VERTICES = 1000, 40000
TORSO = ("Hips", "LHipJoint", "RHipJoint", "LowerBack", "Spine", "Spine1", "LeftShoulder", "RightShoulder",
         "Neck", "Neck1", "Head")
ARMS = tuple(f"{side}{bone}" for side in ("Left", "Right") for bone in ("Arm", "ForeArm", "Hand"))
# Every joint from the shoulders out, fingers included.
ARM_CHAIN = tuple(name for i, name in enumerate(JOINT_NAMES)
                  if any(JOINT_NAMES[a] in ("LeftArm", "RightArm") for a in _ancestors(i)))
LEGS = tuple(f"{side}{bone}" for side in ("Left", "Right") for bone in ("UpLeg", "Leg", "Foot"))
# Grown parts beyond a cut are cut away; listing a part only matters for those a cut does
# not remove (arms beside a skirt would otherwise bulge out of it).


@dataclass(frozen=True)
class Landmarks:
    """Heights and points of the canonical body that garments are cut at (metres)."""

    hip: float          # hip joints
    waist: float        # natural waist, between hips and the lower ribs
    neck: float         # base of the neck
    knee: float
    ankle: float
    shoulder: dict      # side -> (3,) shoulder joint
    elbow: dict         # side -> (3,) elbow joint

    @classmethod
    def of(cls, body: Body) -> "Landmarks":
        p = body.rest_joint_positions.numpy()
        hip = float(p[J["LeftUpLeg"], 2])
        return cls(
            hip=hip,
            waist=float(p[J["Spine"], 2]) - 0.02,
            neck=float(p[J["Neck"], 2]) + 0.01,
            knee=float(p[J["LeftLeg"], 2]),
            ankle=float(p[J["LeftFoot"], 2]),
            shoulder={s: p[J[f"{s}Arm"]] for s in ("Left", "Right")},
            elbow={s: p[J[f"{s}ForeArm"]] for s in ("Left", "Right")},
        )


@dataclass(frozen=True)
class Template:
    """How to cut one garment out of the grown body (lengths in metres)."""

    name: str
    parts: tuple[str, ...]          # body parts (joints) the garment covers
    ease: float                     # gap between body and cloth
    top: str                        # "neck" (a top with sleeves) or "waist"
    bottom: str                     # "hip", "mid-thigh", "knee", "calf", "ankle"
    sleeve: float = 0.0             # sleeve length as a fraction of the upper arm
    skirt_flare: float = 0.0        # extra radius per metre below the waist (0: no skirt hull)
    front_opening: float = 0.0      # width of a front slit (tshirt-open)
    pinned_waist: bool = False


TEMPLATES: dict[str, Template] = {
    "tshirt": Template("tshirt", TORSO + ARMS + LEGS, 0.018, "neck", "hip", sleeve=0.45),
    "tshirt-open": Template("tshirt-open", TORSO + ARMS + LEGS, 0.02, "neck", "hip", sleeve=0.45, front_opening=0.04),
    "pants": Template("pants", TORSO + LEGS, 0.02, "waist", "ankle", pinned_waist=True),
    "long-skirt": Template("long-skirt", TORSO + LEGS, 0.015, "waist", "ankle", skirt_flare=0.25, pinned_waist=True),
    "dress": Template("dress", TORSO + ARMS + LEGS, 0.018, "neck", "calf", sleeve=0.3, skirt_flare=0.2,
                      pinned_waist=True),
    "tight-dress": Template("tight-dress", TORSO + ARMS + LEGS, 0.008, "neck", "mid-thigh", sleeve=0.15,
                            skirt_flare=0.02, pinned_waist=True),
}


def _bottom_height(lm: Landmarks, bottom: str) -> float:
    return {"hip": lm.hip - 0.02, "mid-thigh": (lm.hip + lm.knee) / 2, "knee": lm.knee,
            "calf": (lm.knee + lm.ankle) / 2, "ankle": lm.ankle + 0.06}[bottom]


def _skirt_field(points: np.ndarray, body: Body, top: float, bottom: float, ease: float, flare: float) -> np.ndarray:
    """Signed distance-like field (< 0 inside) of an elliptic skirt enclosing both legs.

    Cross-section semi-axes at each height: the body's half extents at that height or
    above (so the skirt never narrows going down), plus the ease, plus the flare.
    """
    verts = body.rest_vertices.numpy()
    # Hands hang beside the hips in the A-pose: the skirt wraps the legs and hips only.
    on_arm = np.isin(body.skin_weights.argmax(-1).numpy(), [J[p] for p in ARM_CHAIN])
    lower = verts[(verts[:, 2] <= top + SKIRT_TAPER) & (verts[:, 2] >= bottom - 0.05) & ~on_arm]
    levels = np.linspace(bottom - 0.05, top + SKIRT_TAPER, 56)
    half_x = np.zeros_like(levels)
    back, front = np.zeros_like(levels), np.zeros_like(levels)
    for i, z in enumerate(levels):
        band = lower[np.abs(lower[:, 2] - z) < 0.02]
        if len(band):
            half_x[i] = np.abs(band[:, 0]).max()
            front[i], back[i] = band[:, 1].min(), band[:, 1].max()
    # Widest so far from the top down: an A-line.
    order = np.argsort(-levels)
    half_x[order] = np.maximum.accumulate(half_x[order])
    front[order] = np.minimum.accumulate(np.where(front == 0, front.max(), front)[order])
    back[order] = np.maximum.accumulate(back[order])
    z = np.clip(points[:, 2], levels[0], levels[-1])
    drop = np.clip(top - points[:, 2], 0, None)
    a = np.interp(z, levels, half_x) + ease + flare * drop
    b = (np.interp(z, levels, back) - np.interp(z, levels, front)) / 2 + ease + flare * drop
    centre_y = (np.interp(z, levels, back) + np.interp(z, levels, front)) / 2
    # Above its top the hull tapers into the body over SKIRT_TAPER, so the skirt runs
    # smoothly into the grown body instead of ending in a shelf.
    shrink = np.clip(1.0 - (points[:, 2] - top) / SKIRT_TAPER, 0.05, 1.0)
    a, b = a * shrink, b * shrink
    radius = np.sqrt((points[:, 0] / a) ** 2 + ((points[:, 1] - centre_y) / b) ** 2)
    return np.maximum((radius - 1.0) * np.minimum(a, b), points[:, 2] - top - SKIRT_TAPER)


class _Solid:
    """The grown solid of one template on one body, and the planes that cut it open."""

    def __init__(self, spec: Template, body: Body):
        from hyperbones.geometry.proximity import BodyProximity

        self.spec, self.body, self.lm = spec, body, Landmarks.of(body)
        self.top = self.lm.neck if spec.top == "neck" else self.lm.waist
        self.bottom = _bottom_height(self.lm, spec.bottom)
        self.proximity = BodyProximity(body.faces)
        self.proximity.update(body.rest_vertices)
        self.part_ids = [J[p] for p in spec.parts]

    def owner(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,3) points -> (N,) signed distance to the body, (N,) joint owning the nearest face."""
        nearest = self.proximity.query(torch.from_numpy(points.astype(np.float32)), max_distance=1.0)
        joints = self.body.skin_weights[self.body.faces[nearest.face, 0]].argmax(-1).numpy()
        return nearest.signed_distance.numpy(), joints

    def grown(self, points: np.ndarray) -> np.ndarray:
        """(N,3) -> (N,) negative inside the grown body (and skirt)."""
        distance, joints = self.owner(points)
        grown = np.where(np.isin(joints, self.part_ids), distance - self.spec.ease, np.inf)
        if self.spec.skirt_flare:
            skirt_top = self.lm.waist if self.spec.top == "waist" else self.lm.hip
            grown = np.minimum(grown, _skirt_field(points, self.body, skirt_top, self.bottom, self.spec.ease,
                                                   self.spec.skirt_flare))
        return grown

    def cut(self, vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Open the surface: hem, top, sleeve ends, front slit."""
        spec, lm = self.spec, self.lm
        up = np.array([0.0, 0.0, 1.0])
        vertices, faces = slice_mesh(vertices, faces, -up, np.array([0.0, 0.0, self.top]))
        vertices, faces = slice_mesh(vertices, faces, up, np.array([0.0, 0.0, self.bottom]))
        if spec.sleeve:
            _, joints = self.owner(vertices[faces].mean(1))
            for side in ("Left", "Right"):
                on_arm = np.isin(joints, [J[f"{side}Arm"], J[f"{side}ForeArm"], J[f"{side}Hand"]])
                axis = lm.elbow[side] - lm.shoulder[side]
                end = lm.shoulder[side] + spec.sleeve * axis
                vertices, faces = slice_mesh(vertices, faces, -axis / np.linalg.norm(axis), end, on_arm)
                if side == "Left":  # faces changed: find the arm faces again for the other side
                    _, joints = self.owner(vertices[faces].mean(1))
        if spec.front_opening:
            centre = vertices[faces].mean(1)
            front = centre[:, 1] < float(lm.shoulder["Left"][1])  # neckline to hem
            for sign in (1.0, -1.0):
                half = front & (sign * centre[:, 0] > 0)
                vertices, faces = slice_mesh(vertices, faces, np.array([sign, 0.0, 0.0]),
                                             np.array([sign * spec.front_opening / 2, 0.0, 0.0]), half)
                centre = vertices[faces].mean(1)
                front = centre[:, 1] < float(lm.shoulder["Left"][1])
        return largest_piece(vertices, faces)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        verts = self.body.rest_vertices.numpy()
        band = verts[(verts[:, 2] > self.bottom - 0.05) & (verts[:, 2] < self.top + 0.05)]
        margin = self.spec.ease + 0.02 + self.spec.skirt_flare * (self.top - self.bottom)
        lo, hi = band.min(0) - margin, band.max(0) + margin
        lo[2], hi[2] = self.bottom - 0.03, self.top + 0.03
        return lo, hi


def make_template(name: str, body: Body, vertices: int = DEFAULT_VERTICES, voxel: float = 0.006) -> Garment:
    """Build template ``name`` fitted to ``body`` with about ``vertices`` vertices."""
    if name not in TEMPLATES:
        raise ParameterError(f"unknown garment template {name!r}; available: {', '.join(TEMPLATES)}")
    if not MIN_VERTICES <= vertices <= MAX_VERTICES:
        raise ParameterError(f"--vertices must be between {MIN_VERTICES} and {MAX_VERTICES}, got {vertices}")
    spec = TEMPLATES[name]
    solid = _Solid(spec, body)
    lo, hi = solid.bounds()
    surface = surface_from_field(_narrow_band_field(solid.grown, lo, hi, voxel), lo, voxel)
    opened = solid.cut(*surface)
    remeshed_vertices, remeshed_faces = isotropic_remesh(*opened, vertices)
    garment_vertices, garment_faces, uvs, face_uvs = uv_atlas(remeshed_vertices, remeshed_faces)
    pinned = torch.zeros(0, dtype=torch.int64)
    if spec.pinned_waist:
        pin_height = solid.top if spec.top == "waist" else solid.lm.waist
        band = np.abs(garment_vertices[:, 2] - pin_height) < max(0.012, 0.6 * _mean_edge(garment_vertices, garment_faces))
        pinned = torch.from_numpy(np.nonzero(band)[0]).long()
    return Garment(torch.from_numpy(garment_vertices).float(), torch.from_numpy(garment_faces).long(),
                   torch.from_numpy(uvs).float(), torch.from_numpy(face_uvs).long(), pinned, name=name)


def _narrow_band_field(function, lo: np.ndarray, hi: np.ndarray, voxel: float, coarsening: int = 4) -> np.ndarray:
    """Sample ``function`` on a grid, exactly only near its zero set.

    A grid ``coarsening`` times coarser is sampled first; fine samples whose interpolated
    value is within two coarse cells of zero are evaluated exactly, the rest keep the
    interpolation (only the sign matters far from the surface). Body distance queries
    dominate the cost, and most of the box is far from the skin.
    """
    import scipy.ndimage

    shape = np.ceil((hi - lo) / voxel).astype(int) + 1
    coarse_shape = (shape - 1) // coarsening + 2
    coarse_axes = [lo[i] + coarsening * voxel * np.arange(coarse_shape[i]) for i in range(3)]
    coarse_grid = np.stack(np.meshgrid(*coarse_axes, indexing="ij"), -1).reshape(-1, 3)
    coarse = function(coarse_grid).reshape(*coarse_shape)
    coarse = np.where(np.isfinite(coarse), coarse, 1.0)
    index = np.stack(np.meshgrid(*[np.arange(n) / coarsening for n in shape], indexing="ij"), 0).reshape(3, -1)
    field = scipy.ndimage.map_coordinates(coarse, index, order=1, mode="nearest")
    near = np.abs(field) < 2 * coarsening * voxel
    points = lo + voxel * np.stack(np.unravel_index(np.nonzero(near)[0], shape), -1)
    field[near] = function(points)
    return np.where(np.isfinite(field), field, 1.0).reshape(*shape)


def _mean_edge(vertices: np.ndarray, faces: np.ndarray) -> float:
    return float(np.linalg.norm(vertices[faces[:, 0]] - vertices[faces[:, 1]], axis=-1).mean())


__all__ = ["TEMPLATES", "DEFAULT_VERTICES", "make_template", "Landmarks"]
