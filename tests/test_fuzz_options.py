"""Fuzzing the option strings a user types: ``--body`` (``BodyShape.parse``), ``--material``
(``Material.parse``), ``--runtime`` (``runtime.config.parse_overrides``) and ``--source-fps``
(a rate, or CLIP=FPS pairs, through ``hyperbones.cli.main``), with arbitrary text and mutations of
valid strings. Each case parses to valid settings or raises a one-line ParameterError (the CLI:
exits 2 with one line on stderr)."""

from __future__ import annotations

import contextlib
import io
import math

import pytest
from hypothesis import strategies as st
from test_fuzz_support import check_message, fuzz, loads_or_fails_cleanly, mutations, special_numbers

from hyperbones.body.shape import PHENOTYPE_KEYS, BodyShape
from hyperbones.cli import main
from hyperbones.errors import ParameterError
from hyperbones.motion.bvh import MAX_FPS, MIN_FPS
from hyperbones.physics.material import Material
from hyperbones.runtime.config import RuntimeConfig, parse_overrides

MATERIAL_KEYS = ("mu", "lambda", "lame_mu", "lame_lambda", "thickness", "density", "bending")
RUNTIME_KEYS = tuple(RuntimeConfig().as_dict())
VALID = {
    "body": ["gender=0.2,weight=0.8", "age=1,muscle=0,height=0.5,proportions=0.25", "default", ""],
    "material": ["mu=30000,bending=1e-4", "lambda=44400, thickness=4.7e-4,density=0.2", "default"],
    "runtime": ["follow=0.5,untangle=false", "push_rounds=3,contact_margin=0.003,contact=off",
                "projection_iterations=0,loose_follow=1"],
    "fps": ["60", "120.0", "1e2", " 30 "],
    "pairs": ["74_06=60", "143_06=60.0", "clip=1e2"],
}


def option_text(keys: tuple[str, ...], valid: list[str]) -> st.SearchStrategy[str]:
    """Arbitrary text, key=value lists over the known keys (and others) with odd values, and
    mutations of valid strings."""
    value = st.one_of(special_numbers(), st.floats().map(repr), st.text(max_size=8),
                      st.sampled_from(["0.5", "1", "true", "off", "1e-4", "0.999", "2"]))
    key = st.one_of(st.sampled_from(keys), st.text(max_size=8), st.sampled_from(keys).map(str.upper))
    pair = st.tuples(key, st.sampled_from(["=", "==", " = ", "", ":"]), value).map("".join)
    listed = st.lists(pair, max_size=5).flatmap(lambda items: st.sampled_from([",", ", ", ",,", ";"]).map(
        lambda sep: sep.join(items)))
    return st.one_of(st.text(), listed, mutated_valid(valid), listed)


def mutated_valid(valid: list[str]) -> st.SearchStrategy[str]:
    return st.sampled_from(valid).flatmap(
        lambda text: mutations(text.encode()).map(lambda data: data.decode("utf-8", errors="replace")))


def test_fuzz_body_shape_parse():
    def case(text: str):
        shape = loads_or_fails_cleanly(lambda: BodyShape.parse(text))
        if shape is not None:
            assert all(0.0 <= value <= 1.0 for value in shape.as_dict().values())

    fuzz(option_text(PHENOTYPE_KEYS, VALID["body"]), case)


def test_fuzz_material_parse():
    def case(text: str):
        material = loads_or_fails_cleanly(lambda: Material.parse(text))
        if material is not None:
            assert all(math.isfinite(value) and value > 0 for value in material.as_dict().values())

    fuzz(option_text(MATERIAL_KEYS, VALID["material"]), case)


def test_fuzz_runtime_overrides():
    def case(text: str):
        values = loads_or_fails_cleanly(lambda: parse_overrides(text))
        if values is not None:
            config = RuntimeConfig().with_overrides(text)  # the values make a valid config
            assert all(getattr(config, key) == value for key, value in values.items())

    fuzz(option_text(RUNTIME_KEYS, VALID["runtime"]), case)


def test_material_key_given_twice():
    """'mu=1,lame_mu=2' kept the last value silently."""
    for text in ("mu=30000,mu=40000", "mu=30000,lame_mu=40000"):
        with pytest.raises(ParameterError, match="given twice"):
            Material.parse(text)


@pytest.fixture
def stub_verbs(monkeypatch):
    """``motion`` and ``check retarget`` replaced by stubs that keep the parsed --source-fps."""
    from hyperbones.cli import animation, check

    seen = []

    def keep(args):
        seen.append(args.source_fps)
        return 0

    monkeypatch.setattr(animation, "run_motion", keep)
    monkeypatch.setattr(check, "run_retarget", keep)
    return seen


def _run_cli(argv: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exit:
            code = exit.code
    return code, err.getvalue()


def _cli_case(argv: list[str], seen: list):
    code, err = loads_or_fails_cleanly(lambda: _run_cli(argv))
    if code == 0:
        return seen[-1]
    assert code == 2, (argv, code, err)
    assert err.startswith("hyperbones: error: --source-fps") and err.count("\n") == 1, err
    check_message(err.strip())
    return None


def test_fuzz_source_fps(stub_verbs):
    def case(text: str):
        fps = _cli_case(["motion", "walk", f"--source-fps={text}", "--out", "x.npz"], stub_verbs)
        if fps is not None:
            assert isinstance(fps, float) and MIN_FPS <= fps <= MAX_FPS

    fuzz(st.one_of(st.text(), special_numbers(), st.floats().map(repr), mutated_valid(VALID["fps"])), case)


def test_fuzz_source_fps_pairs(stub_verbs):
    def case(texts: list[str]):
        rates = _cli_case(["check", "retarget", "clip.bvh", *(f"--source-fps={text}" for text in texts)], stub_verbs)
        if rates is not None:
            assert len(rates) == len(texts)
            for name, fps in rates:
                assert name.strip() and isinstance(fps, float) and MIN_FPS <= fps <= MAX_FPS

    text = option_text(("74_06", "143_06", ""), VALID["pairs"])
    fuzz(st.lists(st.one_of(text, st.tuples(st.text(max_size=6), special_numbers()).map("=".join)),
                  min_size=1, max_size=3), case)


@pytest.mark.parametrize("argv, phrase", [
    (["motion", "walk", "--source-fps", "0"], "--source-fps: '0' is outside [1, 10000]"),  # accepted before
    (["motion", "walk", "--source-fps", "nan"], "--source-fps: 'nan' is outside"),  # accepted before
    (["motion", "walk", "--source-fps", "fast"], "--source-fps: expected a number"),  # usage lines before
    (["check", "retarget", "x.bvh", "--source-fps", "74_06"], "--source-fps: expected CLIP=FPS"),  # usage lines
    (["check", "retarget", "x.bvh", "--source-fps", "=60"], "--source-fps: expected CLIP=FPS"),  # accepted before
])
def test_source_fps_errors_the_fuzzing_found(stub_verbs, argv, phrase):
    code, err = _run_cli(argv)
    assert code == 2 and err.startswith(f"hyperbones: error: {phrase}") and err.count("\n") == 1
    assert not stub_verbs
