"""The identity cache: everything Module A needs for one body shape × garment, made once.

``encode_identity`` runs Module B (the trunk over the canonical graph, then its heads) and
folds every per-identity quantity into plain tensors, so the per-frame path only multiplies:
  - the garment-from-bone weights softmax(log W0 + Δw) (V,B);
  - the Shape Modulator's FiLM parameters of z (the network never sees z per frame);
  - F_UV, the vertex features rasterised once;
  - the UV raster/sampler matrices and the virtual bones.
It can be saved and loaded (``torch.load(weights_only=True)``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from hyperbones.errors import InputFileError
from hyperbones.geometry.uv_raster import UvRaster
from hyperbones.io_utils import atomic_path, load_versioned
from hyperbones.rig.virtual_bones import VirtualBones
from hyperbones.runtime.garment_proxy import GarmentProxy

if TYPE_CHECKING:
    from hyperbones.body.anny_body import Body
    from hyperbones.garment.garment import Garment
    from hyperbones.models.cloth_graph import ClothGraph
    from hyperbones.models.hyperbones import HyperBonesModel

IDENTITY_VERSION = 2

# What a saved identity holds: entry -> (float or int tensor, shape in named sizes): V vertices,
# F faces, U UVs, B bones, C features, R the UV resolution, L×H the FiLM size, N the nonzeros.
_SAVED = {
    "rest_vertices": ("float", ("V", 3)), "faces": ("int", ("F", 3)), "rest_joint_positions": ("float", (31, 3)),
    "weights": ("float", ("V", "B")), "film": ("float", ("L", 2, "H")), "features_uv": ("float", ("C", "R", "R")),
    "vertex_features": ("float", ("V", "C")), "uvs": ("float", ("U", 2)), "face_uvs": ("int", ("F", 3)),
    "bones.rest_positions": ("float", ("B", 3)), "bones.garment_vertex": ("int", ("B",)),
    "bones.joint_weights": ("float", ("B", 31)), "bones.log_weights": ("float", ("V", "B")),
    "raster.coverage": ("float", ("R", "R")),
    "raster.raster_indices": ("int", (2, "Nr")), "raster.raster_values": ("float", ("Nr",)),
    "raster.sampler_indices": ("int", (2, "Ns")), "raster.sampler_values": ("float", ("Ns",)),
}
# Index entries -> the sizes each row indexes into ("RR": R²).
_INDEXES = {"faces": ("V",), "face_uvs": ("U",), "bones.garment_vertex": ("V",),
            "raster.raster_indices": ("RR", "V"), "raster.sampler_indices": ("V", "RR")}


@dataclass
class Identity:
    """One identity, ready for the per-frame runtime.

    rest_vertices: (V,3) the canonical garment on this body.  faces: (F,3).
    rest_joint_positions: (31,3) the body's canonical joint heads (for forward kinematics).
    bones: the virtual bones.  weights: (V,B) garment-from-bone weights (rows sum to 1).
    film: (layers,2,hidden) FiLM scales and shifts of Bone-Net.
    features_uv: (d_f,R,R) F_UV.  raster: the UV atlas maps at resolution R.
    vertex_features: (V,d_f) f_v, and uvs (U,2), face_uvs (F,3) the atlas: ``at_resolution``
    rebuilds the UV maps at another R from them.
    proxy: the coarse copy the runtime corrects in the garment's place (``with_proxy``), or None.
    """

    name: str
    rest_vertices: torch.Tensor
    faces: torch.Tensor
    rest_joint_positions: torch.Tensor
    bones: VirtualBones
    weights: torch.Tensor
    film: torch.Tensor
    features_uv: torch.Tensor
    raster: UvRaster
    vertex_features: torch.Tensor
    uvs: torch.Tensor
    face_uvs: torch.Tensor
    proxy: GarmentProxy | None = None

    @property
    def num_vertices(self) -> int:
        return self.rest_vertices.shape[0]

    def to(self, device: torch.device | str) -> "Identity":
        return Identity(self.name, self.rest_vertices.to(device), self.faces.to(device),
                        self.rest_joint_positions.to(device), self.bones.to(device), self.weights.to(device),
                        self.film.to(device), self.features_uv.to(device), self.raster.to(device),
                        self.vertex_features.to(device), self.uvs.to(device), self.face_uvs.to(device),
                        self.proxy.to(device) if self.proxy is not None else None)

    def with_proxy(self, count: int) -> "Identity":
        """The same identity with a proxy of about ``count`` vertices (``runtime.garment_proxy``;
        made here unless it has one of that count already), or with none where ``count`` is 0
        or the garment has no more vertices than that."""
        if not count or count >= self.num_vertices:
            return self if self.proxy is None else replace(self, proxy=None)
        if self.proxy is not None and self.proxy.target == count:
            return self
        device = self.rest_vertices.device
        return replace(self, proxy=GarmentProxy.build(self.rest_vertices, self.faces, count).to(device))

    def at_resolution(self, resolution: int) -> "Identity":
        """The same identity with its UV maps (and F_UV) rebuilt at ``resolution``."""
        if resolution == self.raster.resolution:
            return self
        device = self.rest_vertices.device
        raster = UvRaster.build(self.faces.cpu(), self.uvs.cpu(), self.face_uvs.cpu(), self.num_vertices,
                                resolution).to(device)
        features_uv = raster.rasterize(self.vertex_features[None])[0]
        return replace(self, raster=raster, features_uv=features_uv)

    def save(self, path: str | Path) -> Path:
        """Write the cache atomically (plain tensors; sparse maps as COO index/value pairs)."""
        payload = {
            "version": IDENTITY_VERSION, "name": self.name, "rest_vertices": self.rest_vertices,
            "faces": self.faces, "rest_joint_positions": self.rest_joint_positions,
            "bones": self.bones.state_dict(), "weights": self.weights, "film": self.film,
            "features_uv": self.features_uv, "raster": self.raster.state_dict(),
            "vertex_features": self.vertex_features, "uvs": self.uvs, "face_uvs": self.face_uvs,
        }
        if self.proxy is not None:  # optional: a cache without one is still version 2
            payload["proxy"] = self.proxy.state_dict()
        path = Path(path)
        with atomic_path(path) as tmp:
            torch.save(payload, tmp)
        return path

    @classmethod
    def load(cls, path: str | Path, device: torch.device | str = "cpu") -> "Identity":
        """A saved identity; a damaged or inconsistent file is an ``InputFileError`` naming it."""
        payload = load_versioned(path, "identity cache", IDENTITY_VERSION)
        _check_saved(Path(path), payload)
        proxy = None
        if "proxy" in payload:
            try:
                proxy = GarmentProxy.from_state_dict(payload["proxy"], payload["rest_vertices"].shape[0])
            except ValueError as error:
                raise InputFileError(path, f"damaged identity cache: {error}") from None
        return cls(payload["name"], payload["rest_vertices"], payload["faces"], payload["rest_joint_positions"],
                   VirtualBones(**payload["bones"]), payload["weights"], payload["film"], payload["features_uv"],
                   UvRaster.from_state_dict(payload["raster"]), payload["vertex_features"], payload["uvs"],
                   payload["face_uvs"], proxy).to(device)


def _check_saved(path: Path, payload: dict) -> None:
    """The saved tensors are all there, of their kinds, shapes that fit together, finite, and
    with their indices in range (what ``Identity.load`` and the per-frame runtime rely on)."""
    def fail(problem: str):
        raise InputFileError(path, f"damaged identity cache: {problem}")

    if not isinstance(payload.get("name"), str):
        fail("no name")
    for table, keys in (("bones", {"rest_positions", "garment_vertex", "joint_weights", "log_weights"}),
                        ("raster", {"resolution", "coverage", "raster_indices", "raster_values", "raster_shape",
                                    "sampler_indices", "sampler_values", "sampler_shape"})):
        if not isinstance(payload.get(table), dict) or set(payload[table]) != keys:
            fail(f"its {table} entry is not a table of {', '.join(sorted(keys))}")
    resolution = payload["raster"]["resolution"]
    if not isinstance(resolution, int) or isinstance(resolution, bool) or resolution < 1:
        fail(f"UV resolution {resolution!r} is not a positive whole number")
    sizes: dict[str, int] = {"R": resolution}
    tensors: dict[str, torch.Tensor] = {}
    for name, (kind, shape) in _SAVED.items():
        table, _, key = name.rpartition(".")
        value = (payload[table] if table else payload).get(key)
        if not isinstance(value, torch.Tensor) or value.is_complex() or value.dtype == torch.bool or (
                value.is_floating_point() != (kind == "float")):
            fail(f"{name} is not a{'n integer' if kind == 'int' else ' float'} tensor")
        if value.ndim != len(shape) or any(sizes.setdefault(d, n) != n if isinstance(d, str) else d != n
                                           for d, n in zip(shape, value.shape)):
            named = ", ".join(str(d) if isinstance(d, int) else f"{d}={sizes[d]}" if d in sizes else d for d in shape)
            fail(f"{name} has shape {tuple(value.shape)}, expected ({named})")
        tensors[name] = value
    sizes["RR"] = resolution * resolution
    for name, value in tensors.items():
        if name == "bones.log_weights":  # -inf: a bone on another piece of cloth
            bad = torch.isnan(value).any() or (value == float("inf")).any()
        else:
            bad = value.is_floating_point() and not torch.isfinite(value).all()
        if bad:
            fail(f"{name} holds NaN or infinite values")
    for name, bounds in _INDEXES.items():
        rows = tensors[name] if len(bounds) > 1 else tensors[name].reshape(1, -1)
        for row, bound in zip(rows, bounds):
            if row.numel() and (int(row.min()) < 0 or int(row.max()) >= sizes[bound]):
                fail(f"{name} has indices outside [0, {sizes[bound]})")
    for matrix, shape in (("raster", [sizes["RR"], sizes["V"]]), ("sampler", [sizes["V"], sizes["RR"]])):
        stored = payload["raster"][f"{matrix}_shape"]
        if not (isinstance(stored, list) and all(type(n) is int for n in stored) and stored == shape):
            fail(f"raster.{matrix}_shape is {stored!r}, expected {shape}")


@dataclass
class IdentityGeometry:
    """What an identity needs that depends on geometry alone: the virtual bones, the UV maps
    and the canonical graph. Made once; the trainer re-runs only the network on it.

    rest_vertices: (V,3), faces: (F,3), rest_joint_positions: (31,3), graph: the canonical
    ``ClothGraph`` (on the model's device).
    """

    name: str
    rest_vertices: torch.Tensor
    faces: torch.Tensor
    rest_joint_positions: torch.Tensor
    bones: VirtualBones
    raster: UvRaster
    graph: ClothGraph
    uvs: torch.Tensor
    face_uvs: torch.Tensor

    @classmethod
    def build(cls, garment: Garment, body: Body, num_bones: int, uv_resolution: int,
              device: torch.device | str = "cpu", name: str | None = None,
              rest_vertices: torch.Tensor | None = None) -> "IdentityGeometry":
        """``garment`` as it starts (draped) on ``body``; ``rest_vertices`` (V,3): its rest
        shape there, where the virtual bones take their skinning weights (``VirtualBones.bind``)."""
        from hyperbones.geometry.proximity import BodyProximity
        from hyperbones.models.cloth_graph import GarmentTopology, canonical_graph
        from hyperbones.physics.cloth import ClothRest

        bones = VirtualBones.bind(garment, body, num_bones, rest_vertices=rest_vertices)
        raster = UvRaster.build(garment.faces, garment.uvs, garment.face_uvs, garment.num_vertices, uv_resolution)
        rest = ClothRest.from_mesh(garment.vertices, garment.faces, garment.material)
        topology = GarmentTopology.build(rest.rest_vertices, garment.faces, garment.pinned, rest.vertex_masses,
                                         garment.material).to(device)
        proximity = BodyProximity(body.faces.to(device), device=device)
        proximity.update(body.rest_vertices.to(device))
        nearest = proximity.query(garment.vertices.to(device), max_distance=1.0)
        graph = canonical_graph(topology, body.rest_vertices.to(device), body.faces.to(device), nearest)
        return cls(name or garment.name, garment.vertices.to(device), garment.faces.to(device),
                   body.rest_joint_positions.to(device), bones.to(device), raster.to(device), graph,
                   garment.uvs.to(device), garment.face_uvs.to(device))


def apply_encoder(model: HyperBonesModel, geometry: IdentityGeometry, train_trunk: bool = True,
                  latents: torch.Tensor | None = None) -> Identity:
    """Module B on an identity's geometry -> the identity cache (differentiable when grad is
    on; through the shared trunk too unless ``train_trunk`` is False). ``latents``: the
    trunk's output on ``geometry.graph`` when already known (``HyperBonesModel.trunk_latents``)."""
    code = model.encode(geometry.graph, train_trunk, latents)
    weights = torch.softmax(geometry.bones.log_weights + code.weight_corrections, dim=1)
    film = model.runtime.modulator(code.shape_code[None])[0]
    features_uv = geometry.raster.rasterize(code.vertex_features[None])[0]
    return Identity(geometry.name, geometry.rest_vertices, geometry.faces, geometry.rest_joint_positions,
                    geometry.bones, weights, film, features_uv, geometry.raster, code.vertex_features,
                    geometry.uvs, geometry.face_uvs)


def encode_identity(model: HyperBonesModel, garment: Garment, body: Body, name: str | None = None,
                    uv_resolution: int | None = None, rest_vertices: torch.Tensor | None = None) -> Identity:
    """Run Module B for ``garment`` fitted to ``body`` (canonical pose); differentiable when grad is on.

    uv_resolution: R of the UV maps (default: the model's training resolution).
    rest_vertices: (V,3) the garment's rest shape on ``body`` (``draped_garment``'s second
    value), where the bones take their skinning weights; None: ``garment`` itself.
    The virtual bones and the UV maps depend on geometry alone; the network contributes
    Δw, z (as FiLM parameters) and F_UV.
    """
    config = model.config.runtime
    device = next(model.parameters()).device
    geometry = IdentityGeometry.build(garment, body, config.num_bones, uv_resolution or config.uv_resolution,
                                      device, name, rest_vertices=rest_vertices)
    return apply_encoder(model, geometry)
