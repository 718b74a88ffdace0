"""Binary glTF export: every frame read back by independent readers (pygltflib's parser with
this file's own accessor decoding, trimesh for the base mesh) and the Khronos validator's
verdict on a real ``simulate --gltf`` scene."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from hyperbones.cli import main
from hyperbones.errors import ParameterError
from hyperbones.export import SceneMesh, read_frames_npz, write_gltf

VALIDATOR_VERSION = "2.0.0-dev.3.10"
VALIDATE_SCRIPT = Path(__file__).parent / "tools" / "validate_gltf.cjs"
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}
_DTYPES = {5126: np.float32, 5125: np.uint32}


def _accessor(gltf, index: int) -> np.ndarray:
    """One accessor's data, decoded from the GLB's binary chunk: (count,) or (count,k)."""
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    width = _COMPONENTS[accessor.type]
    dtype = np.dtype(_DTYPES[accessor.componentType])
    start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
    stride = view.byteStride or width * dtype.itemsize
    blob = gltf.binary_blob()
    rows = [np.frombuffer(blob, dtype, width, start + row * stride) for row in range(accessor.count)]
    data = np.stack(rows)
    return data[:, 0] if width == 1 else data


def _read_scene(path: Path) -> dict[str, dict]:
    """Each mesh node of a GLB by name: its frames (T,W,3) back in Z up, faces (F,3) and
    material, frames from the base and targets weighted as the animation says at each key."""
    from pygltflib import GLTF2

    gltf = GLTF2().load_binary(str(path))
    keys, weights_of = None, {}
    for animation in gltf.animations:
        for channel in animation.channels:
            sampler = animation.samplers[channel.sampler]
            keys = _accessor(gltf, sampler.input)
            weights_of[channel.target.node] = _accessor(gltf, sampler.output).reshape(len(keys), -1)
    scene = {}
    for index, node in enumerate(gltf.nodes):
        primitive = gltf.meshes[node.mesh].primitives[0]
        base = _accessor(gltf, primitive.attributes.POSITION)
        frames = base[None]
        if primitive.targets:
            deltas = np.stack([_accessor(gltf, target["POSITION"]) for target in primitive.targets])
            frames = base[None] + np.einsum("tk,kwc->twc", weights_of[index], deltas)
        y_up = frames.astype(np.float64)
        z_up = np.stack([y_up[..., 0], -y_up[..., 2], y_up[..., 1]], axis=-1)
        scene[node.name] = dict(frames=z_up, faces=_accessor(gltf, primitive.indices).reshape(-1, 3),
                                material=gltf.materials[primitive.material], keys=keys,
                                uv=None if primitive.attributes.TEXCOORD_0 is None
                                else _accessor(gltf, primitive.attributes.TEXCOORD_0))
    return scene


def _assert_same_vertices(read: dict, frames: np.ndarray, faces: np.ndarray, atol: float = 1e-6) -> None:
    """The glTF mesh holds exactly the input's (T,V,3) frames (a vertex per seam corner) and
    its triangles are the input's, vertex for vertex."""
    assert read["frames"].shape[0] == frames.shape[0]
    source = cKDTree(frames[0]).query(read["frames"][0])[1]  # each glTF vertex's input vertex
    assert set(source) == set(range(frames.shape[1]))  # every input vertex is there
    np.testing.assert_allclose(read["frames"], frames[:, source], atol=atol, rtol=0)
    np.testing.assert_array_equal(np.sort(source[read["faces"]], axis=1), np.sort(faces, axis=1))


def test_every_frame_seams_and_static_mesh_read_back(tmp_path):
    rng = np.random.default_rng(3)
    frames = rng.normal(size=(7, 5, 3)).astype(np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3], [3, 2, 4]])
    uvs = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.25], [0.2, 0.9]])
    face_uvs = np.array([[0, 1, 2], [5, 2, 3], [3, 2, 4]])  # vertex 0 has two UVs: a seam
    floor = rng.normal(size=(5, 3))
    path = write_gltf(tmp_path / "scene.glb", [
        SceneMesh("garment", frames, faces, uvs=uvs, face_uvs=face_uvs, display_color=(0.2, 0.4, 0.8)),
        SceneMesh("floor", floor, faces, display_color=rng.uniform(size=(5, 3)))], fps=24.0)
    scene = _read_scene(path)
    garment = scene["garment"]
    assert garment["frames"].shape == (7, 6, 3)  # one vertex more, at the seam
    _assert_same_vertices(garment, frames, faces)
    np.testing.assert_allclose(garment["keys"], np.arange(7) / 24.0, rtol=1e-6)
    # TEXCOORD_0 is the corner's UV with V flipped (glTF's origin is top left).
    corner_uv = {(int(v), *np.round(uvs[u], 6)) for v, u in zip(faces.ravel(), face_uvs.ravel())}
    source = cKDTree(frames[0]).query(garment["frames"][0])[1]
    read_uv = np.round(np.stack([garment["uv"][:, 0], 1 - garment["uv"][:, 1]], axis=1).astype(np.float64), 6)
    assert {(int(v), *uv) for v, uv in zip(source, read_uv)} == corner_uv
    assert garment["material"].pbrMetallicRoughness.baseColorFactor == pytest.approx([0.2, 0.4, 0.8, 1.0])
    assert garment["material"].doubleSided
    _assert_same_vertices(scene["floor"], floor[None], faces)


def test_trimesh_reads_the_first_frame(tmp_path):
    import trimesh

    rng = np.random.default_rng(0)
    frames = rng.normal(size=(4, 6, 3))
    faces = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 0]])
    path = write_gltf(tmp_path / "a.glb", [SceneMesh("cloth", frames, faces)])
    loaded = trimesh.load(path, force="scene", process=False)
    vertices = next(iter(loaded.geometry.values())).vertices
    y_up = np.stack([frames[0, :, 0], frames[0, :, 2], -frames[0, :, 1]], axis=1)
    np.testing.assert_allclose(vertices, y_up, atol=1e-6)


def test_bad_input_is_one_clear_line(tmp_path):
    vertices = np.zeros((3, 3, 3))
    with pytest.raises(ParameterError, match=r"a\.gltf: the glTF output must end in \.glb"):
        write_gltf(tmp_path / "a.gltf", [SceneMesh("a", vertices, [[0, 1, 2]])])
    with pytest.raises(ParameterError, match="different frame counts"):
        write_gltf(tmp_path / "a.glb", [SceneMesh("a", vertices, [[0, 1, 2]]),
                                        SceneMesh("b", vertices[:2], [[0, 1, 2]])])
    with pytest.raises(ParameterError, match="NaN"):
        write_gltf(tmp_path / "a.glb", [SceneMesh("a", np.full((2, 3, 3), np.nan), [[0, 1, 2]])])
    with pytest.raises(ParameterError, match=r"indices must lie in \[0, 3\)"):
        write_gltf(tmp_path / "a.glb", [SceneMesh("a", vertices, [[0, 1, 5]])])
    assert not list(tmp_path.iterdir())  # nothing half-written


def _validator_dir() -> Path:
    """A folder whose node_modules hold the Khronos validator (installed from the npm registry
    on first use into the user's cache); skips where node is absent (CI has it: there a
    failed install fails the test)."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node and npm are needed for the Khronos glTF validator")
    folder = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "hyperbones" / "node"
    package = folder / "node_modules" / "gltf-validator" / "package.json"
    if not package.exists() or json.loads(package.read_text())["version"] != VALIDATOR_VERSION:
        folder.mkdir(parents=True, exist_ok=True)
        done = subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--prefix", str(folder),
                               f"gltf-validator@{VALIDATOR_VERSION}"], capture_output=True, text=True, timeout=300)
        if done.returncode != 0:
            if os.environ.get("CI"):
                pytest.fail(f"npm could not install gltf-validator: {done.stderr[-500:]}")
            pytest.skip("npm could not install gltf-validator (no registry?)")
    return folder


def test_simulate_gltf_passes_the_khronos_validator_and_reads_back(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["simulate", "--method", "lbs", "--garment", "tshirt", "--vertices", "1500", "--motion", "walk",
                 "--frames", "12", "--out", str(out), "--gltf", "--no-preview", "--quiet"])
    assert code == 0
    assert "scene.glb" in capsys.readouterr().out
    report = subprocess.run(["node", str(VALIDATE_SCRIPT), str(_validator_dir()), str(out / "scene.glb")],
                            capture_output=True, text=True, timeout=300, check=True)
    issues = json.loads(report.stdout)["issues"]
    assert issues["numErrors"] == 0, issues["messages"][:5]
    assert issues["numWarnings"] == 0, issues["messages"][:5]
    contract = read_frames_npz(out / "frames.npz")
    scene = _read_scene(out / "scene.glb")
    _assert_same_vertices(scene["garment"], contract["garment_vertices"].astype(np.float64),
                          contract["garment_faces"])
    _assert_same_vertices(scene["body"], contract["body_vertices"].astype(np.float64), contract["body_faces"])
