"""Fuzzing the garment loaders (``garment.obj_io.load_obj_garment``, ``garment.mhclo.load_mhclo_garment``)
with mutations of a real MakeHuman outfit cut to its first vertices (its ``.mhclo`` and OBJ cut
alike) and of an OBJ the package writes: each case loads a sound garment or raises the package's
one-line error naming the file."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch
from hypothesis import strategies as st
from test_fuzz_support import fuzz, loads_or_fails_cleanly, mutations, number_in_lines, write_case

from hyperbones.errors import InputFileError
from hyperbones.garment.garment import Garment
from hyperbones.garment.mhclo import load_mhclo_garment
from hyperbones.garment.obj_io import load_obj_garment, write_obj_garment

OUTFIT = Path(__file__).resolve().parents[2] / "shared" / "data" / "garments" / "makehuman" / "female_sportsuit01"
KEEP_FACES = 120


def _cut_outfit(keep: int = KEEP_FACES) -> tuple[bytes, bytes]:
    """(.mhclo, .obj) of a patch of ``keep`` faces of the outfit, both cut alike: the OBJ keeps the
    patch's vertices, texture coordinates and faces (renumbered), the .mhclo the bindings of those
    vertices in the same order."""
    obj_lines = (OUTFIT / "female_sportsuit01.obj").read_text().splitlines()
    vertices = [line for line in obj_lines if line.startswith("v ")]
    uvs = [line for line in obj_lines if line.startswith("vt ")]
    faces = [[tuple(int(i) for i in corner.split("/")[:2]) for corner in line.split()[1:]]
             for line in obj_lines if line.startswith("f ")]
    patch, seen = [], {faces[0][0][0]}  # faces reached from the first one across shared vertices
    while len(patch) < keep:
        grown = [f for f in faces if f not in patch and any(v in seen for v, _ in f)]
        patch += grown[: keep - len(patch)]
        seen |= {v for f in patch for v, _ in f}
    kept_v = sorted({v for f in patch for v, _ in f})
    kept_t = sorted({t for f in patch for _, t in f})
    new_v = {old: new for new, old in enumerate(kept_v, start=1)}
    new_t = {old: new for new, old in enumerate(kept_t, start=1)}
    obj = ["# a patch of female_sportsuit01.obj", *(vertices[v - 1] for v in kept_v), *(uvs[t - 1] for t in kept_t)]
    obj += ["f " + " ".join(f"{new_v[v]}/{new_t[t]}" for v, t in f) for f in patch]
    mhclo_lines = (OUTFIT / "female_sportsuit01.mhclo").read_text().splitlines()
    verts = mhclo_lines.index("verts 0")
    end = next(i for i in range(verts + 1, len(mhclo_lines)) if re.match(r"[a-z_]+\b", mhclo_lines[i]))
    bindings = mhclo_lines[verts + 1:end]
    mhclo = [*mhclo_lines[:verts + 1], *(bindings[v - 1] for v in kept_v), *mhclo_lines[end:end + 4]]
    mhclo = [line.replace("female_sportsuit01.obj", "outfit.obj") for line in mhclo]
    return ("\n".join(mhclo) + "\n").encode(), ("\n".join(obj) + "\n").encode()


@pytest.fixture(scope="module")
def outfit() -> tuple[bytes, bytes]:
    if not OUTFIT.exists():
        pytest.skip("../shared/data/garments/makehuman is absent")
    return _cut_outfit()


@pytest.fixture(scope="module")
def objs(outfit, tmp_path_factory) -> list[bytes]:
    """The cut MakeHuman OBJ, and the garment it makes as the package writes it."""
    folder = tmp_path_factory.mktemp("objs")
    garment = load_obj_garment(write_case(folder / "cut.obj", outfit[1]), units="dm", up="Y")
    write_obj_garment(folder / "written.obj", garment)
    return [outfit[1], (folder / "written.obj").read_bytes()]


def _sound(garment: Garment) -> None:
    """What a loaded garment must satisfy for the simulators."""
    v = garment.num_vertices
    assert v >= 3 and len(garment.faces) >= 1
    assert torch.isfinite(garment.vertices).all() and torch.isfinite(garment.uvs).all()
    assert 0 <= int(garment.faces.min()) and int(garment.faces.max()) < v
    assert 0 <= int(garment.face_uvs.min()) and int(garment.face_uvs.max()) < len(garment.uvs)
    assert (garment.faces[:, 0] != garment.faces[:, 1]).all() and (garment.faces[:, 1] != garment.faces[:, 2]).all()


def test_cut_outfit_loads(body, outfit, objs, tmp_path):
    """The unmutated files load: the mutations start from valid ones."""
    write_case(tmp_path / "outfit.obj", outfit[1])
    _sound(load_mhclo_garment(write_case(tmp_path / "outfit.mhclo", outfit[0]), body, piece=0))
    for data in objs:
        _sound(load_obj_garment(write_case(tmp_path / "garment.obj", data)))


def test_fuzz_load_obj_garment(objs, tmp_path):
    @st.composite
    def mutated(draw):
        data = objs[draw(st.integers(0, len(objs) - 1))]
        if draw(st.booleans()):
            data = draw(number_in_lines(data, rb"\s*(v|vt|f)\s"))
        return draw(mutations(data))

    def case(data: bytes):
        path = write_case(tmp_path / "garment.obj", data)
        garment = loads_or_fails_cleanly(lambda: load_obj_garment(path), path)
        if garment is not None:
            _sound(garment)

    fuzz(mutated(), case)


def test_fuzz_load_mhclo_garment(body, outfit, tmp_path):
    """Mostly the .mhclo mutated; a quarter of the cases mutate its OBJ instead (whose errors name the OBJ)."""
    mhclo, obj = outfit

    @st.composite
    def mutated(draw):
        piece = draw(st.sampled_from([None, 0, 1]))
        if draw(st.integers(0, 3)) == 0:
            return mhclo, draw(mutations(obj)), piece
        if draw(st.booleans()):  # a number of a binding or of a scale line, then maybe more
            return draw(mutations(draw(number_in_lines(mhclo, rb"\s*([0-9]|[xyz]_scale)")), min_steps=0)), obj, piece
        return draw(mutations(mhclo)), obj, piece

    def case(files):
        mhclo_data, obj_data, piece = files
        path = write_case(tmp_path / "outfit.mhclo", mhclo_data)
        obj_path = write_case(tmp_path / "outfit.obj", obj_data)
        # The fitted positions come from the binding but are judged on the OBJ's faces: either file may be named.
        garment = loads_or_fails_cleanly(lambda: load_mhclo_garment(path, body, piece=piece), (path, obj_path))
        if garment is not None:
            _sound(garment)
            low, high = body.rest_vertices.amin(0), body.rest_vertices.amax(0)  # a fitted garment lies on the body
            assert (garment.vertices > low - 1.0).all() and (garment.vertices < high + 1.0).all()
            low, high = body.rest_vertices.amin(0), body.rest_vertices.amax(0)  # a fitted garment lies on the body
            assert (garment.vertices > low - 1.0).all() and (garment.vertices < high + 1.0).all()

    fuzz(mutated(), case)


@pytest.mark.parametrize("edit, phrase", [
    (lambda words: words[:3] + ["1e308"] + words[4:], "weight '1e308' is larger than"),
    (lambda words: words[:6] + ["1e38"] + words[7:], "offset '1e38' is larger than"),
    (lambda words: words[:6] + ["50000"] + words[7:], "m outside the body"),
])
def test_mhclo_binding_numbers_that_overflowed(body, outfit, tmp_path, edit, phrase):
    """Huge weights or offsets used to overflow to inf positions (an OverflowError, or a ParameterError
    not naming the file) or to load a vertex kilometres away."""
    mhclo, obj = outfit
    lines = mhclo.decode().split("\n")
    first = lines.index("verts 0") + 1
    lines[first] = " ".join(edit(lines[first].split()))
    write_case(tmp_path / "outfit.obj", obj)
    path = write_case(tmp_path / "outfit.mhclo", "\n".join(lines).encode())
    with pytest.raises(InputFileError, match=re.escape(phrase)) as error:
        load_mhclo_garment(path, body, piece=0)
    assert str(path) in str(error.value)


@pytest.mark.parametrize("distance", ["1e-300", "1e-320"])
def test_mhclo_tiny_scale_distance(body, outfit, tmp_path, distance):
    """A tiny x_scale distance made the scale, and the fitted positions, overflow."""
    mhclo, obj = outfit
    write_case(tmp_path / "outfit.obj", obj)
    text = re.sub(rb"(?m)^(x_scale \d+ \d+) \S+", rb"\1 " + distance.encode(), mhclo)
    path = write_case(tmp_path / "outfit.mhclo", text)
    with pytest.raises(InputFileError, match="m outside the body"):
        load_mhclo_garment(path, body, piece=0)


def test_obj_huge_coordinate(objs, tmp_path):
    """A vertex at 1e308 overflowed the degeneracy test (OverflowError)."""
    path = write_case(tmp_path / "huge.obj", re.sub(rb"(?m)^v \S+", b"v 1e308", objs[0], count=1))
    with pytest.raises(InputFileError, match="larger than 1e\\+06 in magnitude"):
        load_obj_garment(path)
