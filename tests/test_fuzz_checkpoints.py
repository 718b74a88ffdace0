"""Fuzzing the checkpoint loaders (``models.loading``: ``load_checkpoint``, ``hyperbones_payload``,
``teacher_from_checkpoint``, ``load_module_a``): truncated and byte-damaged copies of the shipped
``teacher.pt`` (copied first: the shipped files are never touched), and small checkpoints written
the package's way whose payload is changed as another version or damage would change it (config
tables or keys missing or extra, values of other types, weights missing, extra, reshaped or NaN,
a runtime_config that is not a table), each given to every loader, so that a teacher is also
read where a HyperBones checkpoint is expected and the other way round. Each case builds a model
with finite weights or raises the package's one-line error naming the file."""

from __future__ import annotations

import copy
import io

import pytest
import torch
from hypothesis import strategies as st
from test_fuzz_support import fuzz, loads_or_fails_cleanly, mutations, write_case

from hyperbones.errors import InputFileError
from hyperbones.models.hyperbones import HyperBonesConfig, HyperBonesModel
from hyperbones.models.loading import (SHIPPED_TEACHER, hyperbones_payload, load_checkpoint, load_module_a,
                                       teacher_from_checkpoint)
from hyperbones.models.module_a import ModuleAConfig
from hyperbones.models.teacher import Teacher, TrunkConfig
from hyperbones.training.config import HyperBonesTrainingConfig, TeacherTrainingConfig

TRUNK = TrunkConfig(latent=8, blocks=1)
RUNTIME = ModuleAConfig(num_bones=8, shape_code=8, hidden=16, layers=2, pose_embedding=4, uv_features=4,
                        uv_resolution=16, conv_channels=(4, 8, 4))
LOADERS = {
    "load_checkpoint": load_checkpoint,
    "hyperbones_payload": hyperbones_payload,
    "teacher_from_checkpoint": lambda path: teacher_from_checkpoint(path)[0],
    "load_module_a": load_module_a,
}


def _payloads() -> dict[str, dict]:
    """A small teacher and a small HyperBones checkpoint, as training and ``export_weights`` write them."""
    torch.manual_seed(0)
    teacher = Teacher(TRUNK)
    joint = HyperBonesModel(HyperBonesConfig(TRUNK, RUNTIME))
    some = next(iter(teacher.state_dict()))
    return {
        "teacher": {"model": teacher.state_dict(), "ema": {some: teacher.state_dict()[some] + 1}, "step": 7,
                    "config": TeacherTrainingConfig(model=TRUNK).as_dict()},
        "hyperbones": {"model": joint.state_dict(), "step": 9, "runtime_config": {"follow": 0.5, "contact": True},
                       "config": HyperBonesTrainingConfig(model=TRUNK, runtime=RUNTIME).as_dict()},
    }


PAYLOADS = _payloads()
ODD_VALUES = (None, "64", 64.0, -8, 0, 10**9, True, [8], (4, 8), {"latent": 8}, torch.zeros(2), float("nan"), "")


def _saved(payload) -> bytes:
    out = io.BytesIO()
    torch.save(payload, out)
    return out.getvalue()


@st.composite
def changed_payload(draw) -> bytes:
    """A small checkpoint's payload changed in one to three places, saved with ``torch.save``."""
    payload = copy.deepcopy(PAYLOADS[draw(st.sampled_from(sorted(PAYLOADS)))])
    for _ in range(draw(st.integers(1, 3))):
        part = draw(st.sampled_from(["config", "config", "model", "model", "ema", "runtime_config", "payload"]))
        if part == "payload":
            change = draw(st.sampled_from(["drop model", "drop config", "list", "tensor", "step"]))
            if change.startswith("drop"):
                payload.pop(change.split()[1], None)
            elif change == "list":
                payload = [payload]
            elif change == "tensor":
                payload = torch.ones(3)
            else:
                payload["step"] = draw(st.sampled_from(ODD_VALUES))
            if not isinstance(payload, dict):
                break
        elif part == "config":
            config = payload.setdefault("config", {})
            section = draw(st.sampled_from(["model", "runtime", "data", "train", "joint", "extra"]))
            change = draw(st.sampled_from(["drop section", "drop key", "extra key", "value", "section value"]))
            table = config.get(section)
            if change == "drop section":
                config.pop(section, None)
            elif change == "section value":
                config[section] = draw(st.sampled_from(ODD_VALUES))
            elif isinstance(table, dict) and table:
                key = draw(st.sampled_from(sorted(table)))
                if change == "drop key":
                    table.pop(key)
                elif change == "extra key":
                    table[f"{key}_v2"] = table[key]
                else:
                    table[key] = draw(st.sampled_from(ODD_VALUES))
        elif part in ("model", "ema"):
            state = payload.get(part)
            if not isinstance(state, dict) or not state:
                payload[part] = draw(st.sampled_from([{}, None, [1], {"x": 1}, torch.ones(2), 0]))
                continue
            name = draw(st.sampled_from(sorted(state)))
            change = draw(st.sampled_from(["drop", "extra", "reshape", "nan", "inf", "int", "not a tensor",
                                           "complex", "scalar", "rename"]))
            if not isinstance(state[name], torch.Tensor):  # an earlier change made it so
                continue
            value = state.pop(name)
            if change == "extra":
                state[name], state[f"{name}.extra"] = value, value
            elif change == "reshape":
                state[name] = value.reshape(-1)[:-1] if value.numel() > 1 else value.reshape(1, 1)
            elif change in ("nan", "inf"):
                state[name] = torch.full_like(value, float(change)) if value.is_floating_point() else value
            elif change == "int":
                state[name] = value.to(torch.int64)
            elif change == "not a tensor":
                state[name] = value.tolist()
            elif change == "complex":
                state[name] = value.to(torch.complex64)
            elif change == "scalar":
                state[name] = torch.tensor(1.0)
            elif change == "rename":
                state[name.replace(".", "_", 1)] = value
        else:
            payload["runtime_config"] = draw(st.sampled_from([{"follow": float("nan")}, {"unknown": 1}, [0.5], "x",
                                                              {1: 2}, {"follow": "fast"}, None, torch.ones(2)]))
    return _saved(payload)


@st.composite
def damaged_teacher(draw, shipped: bytes) -> bytes:
    """The shipped teacher truncated, or with bytes flipped, inserted, deleted or zeroed."""
    if draw(st.booleans()):
        return shipped[:draw(st.integers(0, len(shipped) - 1))]
    return draw(mutations(shipped, text=False))


@pytest.fixture(scope="module")
def shipped_teacher() -> bytes:
    return SHIPPED_TEACHER.read_bytes()  # read only; cases write their copies elsewhere


def _sound(loaded) -> None:
    if isinstance(loaded, torch.nn.Module):
        assert all(torch.isfinite(value).all() for value in loaded.state_dict().values())
    else:
        assert isinstance(loaded, dict) and isinstance(loaded["model"], dict) and isinstance(loaded["config"], dict)


def _case(folder):
    def case(drawn):
        data, loader = drawn
        path = write_case(folder / "checkpoint.pt", data)
        _sound_or_none = loads_or_fails_cleanly(lambda: LOADERS[loader](path), path)
        if _sound_or_none is not None:
            _sound(_sound_or_none)

    return case


def test_small_checkpoints_load(tmp_path):
    """The unchanged small checkpoints load where they belong, and are refused where they do not."""
    teacher = write_case(tmp_path / "teacher.pt", _saved(PAYLOADS["teacher"]))
    joint = write_case(tmp_path / "hyperbones.pt", _saved(PAYLOADS["hyperbones"]))
    assert teacher_from_checkpoint(teacher)[0].config == TRUNK and teacher_from_checkpoint(joint)[0].config == TRUNK
    assert load_module_a(joint).config == RUNTIME and "runtime" in hyperbones_payload(joint)["config"]
    for loader in (hyperbones_payload, load_module_a):
        with pytest.raises(InputFileError, match="a teacher checkpoint, not a HyperBones one"):
            loader(teacher)


def test_fuzz_damaged_shipped_teacher(shipped_teacher, tmp_path):
    fuzz(st.tuples(damaged_teacher(shipped_teacher), st.sampled_from(sorted(LOADERS))), _case(tmp_path))


def test_fuzz_changed_payloads(tmp_path):
    fuzz(st.tuples(changed_payload(), st.sampled_from(sorted(LOADERS))), _case(tmp_path))


def test_shipped_teacher_untouched(shipped_teacher):
    assert SHIPPED_TEACHER.read_bytes() == shipped_teacher


def _changed(name: str, change) -> bytes:
    payload = copy.deepcopy(PAYLOADS[name])
    change(payload)
    return _saved(payload)


@pytest.mark.parametrize("data, loader, phrase", [
    (b"", "load_checkpoint", "not a hyperbones checkpoint (EOFError: )"),  # an empty message: an IndexError before
    (_changed("teacher", lambda p: p["config"]["model"].pop("blocks")), "teacher_from_checkpoint",
     "its teacher weights do not match its config"),  # blocks took the default, 15: a multi-line RuntimeError
    (_changed("teacher", lambda p: p["config"]["model"].update(latent=10**9)), "teacher_from_checkpoint",
     "its config's model.latent = 1000000000 is not a valid value"),  # would build a 10^9-wide model
    (_changed("teacher", lambda p: p["config"]["model"].update(width=8)), "teacher_from_checkpoint",
     "its config's [model] has unknown key(s) ['width']"),  # a TypeError before
    (_changed("hyperbones", lambda p: p["config"]["runtime"].pop("hidden")), "load_module_a",
     "its Module A weight"),  # hidden took the default, 256: a multi-line RuntimeError before
    (_changed("hyperbones", lambda p: p["config"]["runtime"].pop("num_bones")), "hyperbones_payload",
     "its HyperBones weight"),  # Module B's heads are sized by the bone count
    (_changed("hyperbones", lambda p: p.update(ema=torch.ones(2))), "hyperbones_payload",
     "its ema state is not a dict of tensors"),  # ambiguous truth value of a tensor before
    (_changed("hyperbones", lambda p: p["model"]["runtime.refiner.out.bias"].fill_(float("nan"))), "load_module_a",
     "weight runtime.refiner.out.bias of its model state holds NaN"),  # loaded silently before
    (_changed("hyperbones", lambda p: p.update(runtime_config=[0.5])), "hyperbones_payload",
     "its runtime_config is not a table"),  # a TypeError in the simulator before
    (_changed("hyperbones", lambda p: p.update(config=[])), "hyperbones_payload", "its config is not a dict"),
])
def test_checkpoints_the_fuzzing_found(tmp_path, data, loader, phrase):
    path = write_case(tmp_path / "found.pt", data)
    with pytest.raises(InputFileError) as error:
        LOADERS[loader](path)
    assert phrase in str(error.value) and str(error.value).startswith(str(path)) and "\n" not in str(error.value)
