"""Fuzzing ``training.config.load_config`` with mutations of the shipped ``configs/*.toml``: each
case loads a config whose every field has its declared type (finite numbers, tuples of the
declared length) or raises the package's one-line error naming the file."""

from __future__ import annotations

import math
from dataclasses import fields, is_dataclass
from pathlib import Path
from typing import get_args, get_origin, get_type_hints

import pytest
from hypothesis import strategies as st
from test_fuzz_support import fuzz, loads_or_fails_cleanly, mutations, number_in_lines, write_case

from hyperbones.errors import InputFileError
from hyperbones.training.config import load_config

CONFIGS = sorted((Path(__file__).resolve().parents[1] / "configs").glob("*.toml"))
# Values a mutation puts in place of a value: other TOML types, and keys and tables of other versions.
OTHER_VALUES = (b'"text"', b"true", b"[1, 2]", b"[]", b"{}", b"nan", b"-inf", b"1e400", b"-5", b"0", b"[1.5]",
                b'["a", 1]', b"{ a = 1 }", b"1979-05-27", b"0x10", b"9223372036854775808")
OTHER_LINES = (b"[model]", b"[joint]", b"[runtime]", b"[extra]", b"[data.source_fps]", b"unknown_key = 1",
               b"[[train]]", b"hop_speeds = [1.0]", b"hop_speeds = [1.0, 2.0, 3.0]", b"conv_channels = [1, 2]",
               b'source_fps = { "74_06" = "fast" }', b"resolutions = [1500.5]", b"templates = [1]",
               b"steps = 1e3", b"latent = -64", b"ema_decay = nan", b"bank = 3")


@st.composite
def mutated_config(draw) -> bytes:
    data = CONFIGS[draw(st.integers(0, len(CONFIGS) - 1))].read_bytes()
    choice = draw(st.integers(0, 3))
    lines = data.split(b"\n")
    settings = [i for i, line in enumerate(lines) if b"=" in line and not line.startswith(b"#")]
    if choice == 0 and settings:  # a value replaced by another TOML type or a special number
        i = settings[draw(st.integers(0, len(settings) - 1))]
        lines[i] = lines[i].split(b"=")[0] + b"= " + draw(st.sampled_from(OTHER_VALUES))
        data = b"\n".join(lines)
    elif choice == 1:  # a line of another version or section inserted
        lines.insert(draw(st.integers(0, len(lines))), draw(st.sampled_from(OTHER_LINES)))
        data = b"\n".join(lines)
    elif choice == 2:
        data = draw(number_in_lines(data, rb"[a-z_]+ *="))
    return draw(mutations(data, min_steps=0 if choice < 3 else 1))


def _well_typed(config, where: str = "config") -> None:
    """Every field of the (nested) dataclass has its declared type; numbers are finite and (but the
    seed) not negative."""
    hints = get_type_hints(type(config))
    for item in fields(config):
        value, kind = getattr(config, item.name), hints[item.name]
        _check_value(value, kind, f"{where}.{item.name}")


def _check_value(value, kind, where: str) -> None:
    if is_dataclass(kind):
        assert isinstance(value, kind), where
        _well_typed(value, where)
    elif get_origin(kind) is tuple:
        args = get_args(kind)
        assert isinstance(value, tuple), where
        if Ellipsis not in args:
            assert len(value) == len(args), f"{where}: {len(value)} items, declared {len(args)}"
        for item in value:
            _check_value(item, args[0], where)
    elif get_origin(kind) is dict:
        assert isinstance(value, dict), where
        for item in value.values():
            _check_value(item, get_args(kind)[1], where)
    elif kind is float:
        assert isinstance(value, float) and math.isfinite(value), f"{where} = {value!r}"
        assert value >= 0, f"{where} = {value!r}"
    elif kind is int:
        assert isinstance(value, int) and not isinstance(value, bool), f"{where} = {value!r}"
        assert value >= 0 or where == "config.train.seed", f"{where} = {value!r}"
    else:
        assert isinstance(value, kind), f"{where} = {value!r}"


def test_shipped_configs_are_well_typed():
    for path in CONFIGS:
        _well_typed(load_config(path))


def test_fuzz_load_config(tmp_path):
    def case(data: bytes):
        path = write_case(tmp_path / "config.toml", data)
        config = loads_or_fails_cleanly(lambda: load_config(path), path)
        if config is not None:
            _well_typed(config)

    fuzz(mutated_config(), case)


@pytest.mark.parametrize("text, problem", [
    ("[joint]\nmax_rise = nan\n", "joint.max_rise must be a finite number, got nan"),
    ("[train]\nlearning_rate = inf\n", "train.learning_rate must be a finite number"),
    ("[data]\nhop_speeds = [1.0]\n", "data.hop_speeds must be a list of 2"),
    ("[runtime]\nconv_channels = [64, 128]\n[joint]\n", "runtime.conv_channels must be a list of 3"),
    ("[model]\nlatent = -64\n", "model.latent must be >= 0, got -64"),
    ("[data]\nsource_fps = { 74_06 = -60 }\n", "data.source_fps must be >= 0"),
])
def test_values_the_fuzzing_found_loaded(tmp_path, text, problem):
    """These loaded silently (NaN weights, a one-item speed range, a negative size) before."""
    path = write_case(tmp_path / "found.toml", text.encode())
    with pytest.raises(InputFileError) as error:
        load_config(path)
    assert problem in str(error.value) and str(path) in str(error.value)


def test_seed_may_be_negative(tmp_path):
    assert load_config(write_case(tmp_path / "seed.toml", b"[train]\nseed = -3\n")).train.seed == -3
