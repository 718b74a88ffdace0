"""Write animated triangle meshes to a binary glTF 2.0 file (.glb), one morph target a frame.

glTF has no point caches; the way three.js, Blender and Babylon.js all import a vertex
animation is morph targets with an animated weight: frame 0 is the mesh, frame t (t ≥ 1) its
target t−1 (the displacement from frame 0), and one animation sets target t−1's weight to 1
at time t / fps and every other to 0. Its LINEAR interpolation blends two neighbouring
frames, so a player at another rate sees the positions interpolated linearly. Skinning the
body instead would be smaller but only approximate Anny's skinning (glTF's 4 or 8
influences a vertex); morph targets reproduce every vertex exactly (float32).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hyperbones.errors import ParameterError
from hyperbones.export._checks import check_positive
from hyperbones.export.scene_mesh import CheckedMesh, SceneMesh, checked_meshes
from hyperbones.io_utils import atomic_path

GLTF_SUFFIX = ".glb"
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UNSIGNED_INT = 5126, 5125
_TRIANGLES = 4


def write_gltf(path: str | Path, meshes: list[SceneMesh], fps: float = 30.0) -> Path:
    """Write ``meshes`` to a binary glTF 2.0 file at ``path`` (``.glb``).

    Y up and metres, as glTF requires: the Z-up input is turned (x,y,z) -> (x,z,−y), so a
    body facing −Y faces glTF's front (+Z). Each mesh is a node of the one scene, with a
    material of its ``display_color`` (per-vertex colours as COLOR_0; the garment is drawn
    from both sides) and, with UVs, TEXCOORD_0 (V flipped to glTF's top-left origin; vertices
    split where the UVs have seams). Animated meshes (T,V,3) get T−1 morph targets and one
    weight animation over T frames at ``fps`` (see the module). Written atomically.
    """
    from pygltflib import GLTF2

    path = Path(path)
    if path.suffix.lower() != GLTF_SUFFIX:
        raise ParameterError(f"{path}: the glTF output must end in .glb")
    fps = check_positive("fps", fps)
    checked = checked_meshes(meshes, "Y", 1.0, "write_gltf")
    document = _Document()
    for mesh in checked:
        document.add_mesh(mesh)
    document.animate(fps)
    gltf = GLTF2().from_dict(document.as_dict())
    gltf.set_binary_blob(document.blob())
    with atomic_path(path) as tmp:
        gltf.save_binary(str(tmp))
    return path


def split_at_seams(mesh: CheckedMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """One glTF vertex per distinct (vertex, UV) pair of the face corners: (W,) the source
    vertex of each, (F,3) the faces over them, (W,2) their UVs (None without UVs)."""
    if mesh.uv is None:
        return np.arange(mesh.points.shape[-2]), mesh.faces, None
    coords, face_uvs = mesh.uv
    corners = np.stack([mesh.faces.reshape(-1), face_uvs.reshape(-1)], axis=1)  # (3F,2)
    pairs, inverse = np.unique(corners, axis=0, return_inverse=True)
    return pairs[:, 0], inverse.reshape(mesh.faces.shape), coords[pairs[:, 1]]


class _Document:
    """The glTF JSON being built and its binary chunk (every accessor 4-byte aligned)."""

    def __init__(self):
        self.chunks: list[bytes] = []
        self.length = 0
        self.json: dict = {"asset": {"version": "2.0", "generator": "hyperbones"}, "scene": 0,
                           "scenes": [{"nodes": []}], "nodes": [], "meshes": [], "materials": [],
                           "accessors": [], "bufferViews": [], "animations": []}
        self.animated: list[int] = []  # the nodes with morph targets, all of ``frames`` frames
        self.frames = 1

    def view(self, data: np.ndarray, target: int | None, stride: int | None = None) -> int:
        """A buffer view over ``data``'s bytes (``stride``: bytes per vertex, needed where
        several vertex accessors share the view); returns its index."""
        raw = np.ascontiguousarray(data).tobytes()
        view = {"buffer": 0, "byteOffset": self.length, "byteLength": len(raw)}
        if target is not None:
            view["target"] = target
        if stride is not None:
            view["byteStride"] = stride
        self.chunks.append(raw + b"\0" * (-len(raw) % 4))
        self.length += len(raw) + (-len(raw) % 4)
        self.json["bufferViews"].append(view)
        return len(self.json["bufferViews"]) - 1

    def accessor(self, view: int, data: np.ndarray, kind: str, bounds: bool = False, offset: int = 0) -> int:
        """An accessor of ``data`` (N,k) float32 or (N,) uint32 at ``offset`` bytes into ``view``."""
        entry = {"bufferView": view, "byteOffset": offset, "count": int(data.shape[0]), "type": kind,
                 "componentType": _UNSIGNED_INT if data.dtype == np.uint32 else _FLOAT}
        if bounds:
            flat = data.reshape(data.shape[0], -1)
            entry["min"] = [float(v) for v in flat.min(axis=0)]
            entry["max"] = [float(v) for v in flat.max(axis=0)]
        self.json["accessors"].append(entry)
        return len(self.json["accessors"]) - 1

    def add_mesh(self, mesh: CheckedMesh) -> None:
        source, faces, uvs = split_at_seams(mesh)
        frames = mesh.points if mesh.points.ndim == 3 else mesh.points[None]  # (T,V,3)
        positions = frames[:, source]  # (T,W,3) float32
        base = positions[0]
        attributes = {"POSITION": self.accessor(self.view(base, _ARRAY_BUFFER), base, "VEC3", bounds=True)}
        if uvs is not None:
            texcoord = np.stack([uvs[:, 0], 1.0 - uvs[:, 1]], axis=1).astype(np.float32)
            attributes["TEXCOORD_0"] = self.accessor(self.view(texcoord, _ARRAY_BUFFER), texcoord, "VEC2")
        material: dict = {"name": mesh.name, "doubleSided": True,
                          "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 0.9}}
        if mesh.color is not None and len(mesh.color) == 1:
            material["pbrMetallicRoughness"]["baseColorFactor"] = [*map(float, mesh.color[0]), 1.0]
        elif mesh.color is not None:
            colors = np.ascontiguousarray(mesh.color[source], dtype=np.float32)
            attributes["COLOR_0"] = self.accessor(self.view(colors, _ARRAY_BUFFER), colors, "VEC3")
        self.json["materials"].append(material)
        indices = faces.reshape(-1).astype(np.uint32)
        primitive = {"attributes": attributes, "mode": _TRIANGLES, "material": len(self.json["materials"]) - 1,
                     "indices": self.accessor(self.view(indices, _ELEMENT_ARRAY_BUFFER), indices, "SCALAR")}
        entry: dict = {"name": mesh.name, "primitives": [primitive]}
        targets = len(positions) - 1
        if targets:
            deltas = positions[1:] - base  # (T−1,W,3)
            view = self.view(deltas, _ARRAY_BUFFER, stride=12)
            primitive["targets"] = [
                {"POSITION": self.accessor(view, delta, "VEC3", bounds=True, offset=index * delta.nbytes)}
                for index, delta in enumerate(deltas)]
            entry["weights"] = [0.0] * targets
        self.json["meshes"].append(entry)
        node = len(self.json["nodes"])
        self.json["nodes"].append({"name": mesh.name, "mesh": len(self.json["meshes"]) - 1})
        self.json["scenes"][0]["nodes"].append(node)
        if targets:
            self.animated.append(node)
            self.frames = targets + 1

    def animate(self, fps: float) -> None:
        """One animation (a player's one clip) over the animated nodes: frame t shown at
        t / fps, its target t−1 at weight 1 and the others at 0 (frame 0: none)."""
        if not self.animated:
            return
        times = (np.arange(self.frames, dtype=np.float64) / fps).astype(np.float32)
        weights = np.eye(self.frames, dtype=np.float32)[:, 1:].reshape(-1)  # (T·(T−1),)
        time_accessor = self.accessor(self.view(times, None), times, "SCALAR", bounds=True)
        weight_accessor = self.accessor(self.view(weights, None), weights, "SCALAR")
        sampler = {"input": time_accessor, "output": weight_accessor, "interpolation": "LINEAR"}
        self.json["animations"].append({
            "name": "simulation", "samplers": [sampler],
            "channels": [{"sampler": 0, "target": {"node": node, "path": "weights"}} for node in self.animated]})

    def as_dict(self) -> dict:
        document = dict(self.json, buffers=[{"byteLength": self.length}])
        return {key: value for key, value in document.items() if value != []}

    def blob(self) -> bytes:
        return b"".join(self.chunks)
