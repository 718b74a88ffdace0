"""Loading trained models: checkpoints written atomically and read without executing pickled
code, the shipped teacher and HyperBones model, and the models built from them.

A HyperBones checkpoint may leave its teacher (Module C) out and record that it is read from
a teacher checkpoint beside it (``TEACHER_FROM``): the shipped ``hyperbones.pt`` does, since
its teacher is the shipped ``teacher.pt`` bit for bit. ``load_checkpoint`` puts it back, so
every reader sees the whole model; ``without_teacher`` makes such a payload.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, get_args, get_origin, get_type_hints

import torch

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.io_utils import atomic_path
from hyperbones.models.module_a import ModuleA, ModuleAConfig

if TYPE_CHECKING:
    from hyperbones.models.teacher import Teacher

SHIPPED_TEACHER = Path(__file__).resolve().parent.parent / "checkpoints" / "teacher.pt"
"""The committed teacher (``hyperbones simulate --method teacher`` loads it by default)."""

SHIPPED_HYPERBONES = SHIPPED_TEACHER.with_name("hyperbones.pt")
"""The shipped HyperBones model (``--method hyperbones`` and ``Simulator.load`` default to it)."""

TEACHER_FROM = "teacher_from"
"""A HyperBones checkpoint's record that its teacher is not stored in it but read from a teacher
checkpoint in the same folder: ``{"file": name, "sha256": state_digest of the teacher's weights}``
(the digest, so a teacher file replaced since is refused rather than silently used)."""

MAX_MODEL_SIZE = 4096
"""Largest size a checkpoint's model config may state (a width, a block or bone count, a UV
resolution): larger ones are damage, and would build an enormous model before any check."""


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu",
                    teacher_beside: bool = True) -> dict[str, Any]:
    """Load a checkpoint without executing pickled code; one-line errors name the file. A teacher
    recorded as read from a file beside it (``TEACHER_FROM``) is put back, the record dropped;
    ``teacher_beside`` False refuses such a checkpoint (the teacher file of one)."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(path, "checkpoint not found")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as error:  # noqa: BLE001 - torch raises many kinds for a bad file
        first_line = next(iter(str(error).splitlines()), "").strip()
        raise InputFileError(path, f"not a hyperbones checkpoint ({type(error).__name__}: {first_line})") from None
    if not isinstance(payload, dict) or "model" not in payload or "config" not in payload:
        raise InputFileError(path, "not a hyperbones checkpoint (no model state or config)")
    _check_contents(path, payload)
    if TEACHER_FROM in payload:
        if not teacher_beside:
            raise InputFileError(path, "not a teacher checkpoint (it reads its own teacher from another file)")
        _put_teacher_back(path, payload, map_location)
    if payload.get("ema"):
        payload["ema"] = {**payload["model"], **payload["ema"]}  # entries left out equal the model's
    return payload


def state_digest(state: dict[str, torch.Tensor]) -> str:
    """The SHA-256 of a state dict's names, dtypes, shapes and bytes: equal digests, bit-identical weights."""
    digest = hashlib.sha256()
    for name in sorted(state):
        value = state[name].detach().cpu().contiguous()
        digest.update(f"{name}:{value.dtype}:{tuple(value.shape)};".encode())
        digest.update(value.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def _put_teacher_back(path: Path, payload: dict, map_location: str | torch.device) -> None:
    """Fill in the teacher of a checkpoint saved by ``without_teacher`` from the file it names,
    which must still hold the weights it was saved with."""
    record = payload.pop(TEACHER_FROM)
    name = record.get("file") if isinstance(record, dict) else None
    if not (isinstance(name, str) and name not in ("", ".", "..") and Path(name).name == name
            and isinstance(record.get("sha256"), str)):
        raise InputFileError(path, f"its {TEACHER_FROM} record is not a file name beside it and a digest")
    if "runtime" not in payload["config"]:
        raise InputFileError(path, f"a teacher checkpoint with a {TEACHER_FROM} record (only a HyperBones one has)")
    source = path.with_name(name)
    if not source.is_file() or source.resolve() == path.resolve():
        raise InputFileError(path, f"its teacher is read from {name} beside it, which is missing")
    teacher = load_checkpoint(source, map_location, teacher_beside=False)
    if "runtime" in teacher["config"]:
        raise InputFileError(path, f"its teacher is read from {name} beside it, which is not a teacher checkpoint")
    state = teacher_state(teacher)
    if state_digest(state) != record["sha256"]:
        raise InputFileError(path, f"its teacher is read from {name} beside it, which holds other weights "
                                   f"than it was saved with (replaced since?)")
    payload["model"] = {**{f"teacher.{key}": value for key, value in state.items()}, **payload["model"]}


def without_teacher(payload: dict, teacher_path: str | Path) -> dict:
    """A loaded HyperBones checkpoint's ``payload`` with its teacher left out and recorded as read
    from ``teacher_path``, which must hold the same teacher bit for bit (model, and moving
    average where kept) and lie in the folder the result is saved to (``TEACHER_FROM``)."""
    teacher_path = Path(teacher_path)
    if "runtime" not in payload["config"]:
        raise ParameterError("a teacher checkpoint has no teacher to leave out (a HyperBones one has)")
    state = teacher_state(load_checkpoint(teacher_path, teacher_beside=False))
    ours = {f"teacher.{key}": value for key, value in state.items()}
    for part in ("model", "ema"):
        if not payload.get(part):  # no moving average kept
            continue
        kept = {name: value for name, value in payload[part].items() if name.startswith("teacher.")}
        differ = sorted(set(kept) ^ set(ours)) or [name for name in sorted(ours) if kept[name].dtype != ours[name].dtype
                                                   or not torch.equal(kept[name], ours[name])]
        if differ:
            raise InputFileError(teacher_path, f"not the teacher of this model: {len(differ)} weight(s) of its "
                                               f"{part} state differ (e.g. {differ[0]})")
    model = {name: value for name, value in payload["model"].items() if not name.startswith("teacher.")}
    slim = {**payload, "model": model}
    if payload.get("ema"):  # only the entries that differ from the model's, as training saves it
        slim["ema"] = {name: value for name, value in payload["ema"].items() if not name.startswith("teacher.")
                       and not (name in model and torch.equal(value, model[name]))}
    slim[TEACHER_FROM] = {"file": teacher_path.name, "sha256": state_digest(state)}
    return slim


def _check_contents(path: Path, payload: dict) -> None:
    """The payload's parts have the types the loaders read them as, and its weights are finite."""
    config = payload["config"]
    if not isinstance(config, dict) or not all(isinstance(table, dict) for table in config.values()):
        raise InputFileError(path, "not a hyperbones checkpoint (its config is not a dict of tables)")
    for part in ("model", "ema"):
        state = payload.get(part)
        if part == "ema" and (state is None or isinstance(state, dict) and not state):  # none kept
            continue
        if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
            raise InputFileError(path, f"not a hyperbones checkpoint (its {part} state is not a dict of tensors)")
        for name, value in state.items():
            if (value.is_floating_point() or value.is_complex()) and not torch.isfinite(value).all():
                raise InputFileError(path, f"weight {name} of its {part} state holds NaN or infinite values")
    runtime = payload.get("runtime_config")
    if runtime is not None and not (isinstance(runtime, dict) and all(
            isinstance(k, str) and isinstance(v, (bool, int, float)) and math.isfinite(v) for k, v in runtime.items())):
        raise InputFileError(path, "its runtime_config is not a table of finite numbers and booleans")


def _short(value: Any, limit: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _fits(kind, value) -> bool:
    """Whether ``value`` is a valid stored value of a model-config field of type ``kind``."""
    if kind is bool or kind is str:
        return isinstance(value, kind)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= MAX_MODEL_SIZE
    if get_origin(kind) is tuple:
        items = get_args(kind)
        return isinstance(value, (list, tuple)) and len(value) == len(items) and all(map(_fits, items, value))
    return False


def _model_config(path: Path, payload: dict, section: str, kind):
    """The ``kind`` (``TrunkConfig``, ``ModuleAConfig``) of the checkpoint's config table ``section``;
    a missing table, unknown key or bad value (a checkpoint of another version, or damage) is an
    ``InputFileError`` naming the file. Keys it lacks take the defaults, as for older checkpoints."""
    values = payload["config"].get(section)
    if not isinstance(values, dict):
        raise InputFileError(path, f"its config has no [{section}] table")
    hints = get_type_hints(kind)
    unknown = sorted(set(values) - set(hints))
    if unknown:
        raise InputFileError(path, f"its config's [{section}] has unknown key(s) {unknown}; known: {sorted(hints)}")
    for key, value in values.items():
        if not _fits(hints[key], value):
            raise InputFileError(path, f"its config's {section}.{key} = {_short(value)} is not a valid value")
    try:
        return kind.from_dict(values) if hasattr(kind, "from_dict") else kind(**values)
    except ParameterError as error:
        raise InputFileError(path, f"its config's [{section}]: {error}") from None


def _check_state(path: Path, build, state: dict[str, torch.Tensor], what: str) -> None:
    """``state`` has exactly the entries, shapes and kinds (floating or not) of the model ``build()``
    makes, which is built on the meta device (no memory, no initialisation) to compare with."""
    with torch.device("meta"):
        expected: dict[str, torch.Tensor] = build().state_dict()
    missing, unexpected = sorted(set(expected) - set(state)), sorted(set(state) - set(expected))
    if missing or unexpected:
        listed = [f"{len(names)} {kind} (e.g. {names[0]})" for kind, names in
                  (("missing", missing), ("unexpected", unexpected)) if names]
        raise InputFileError(path, f"its {what} weights do not match its config: {', '.join(listed)}")
    for name, want in expected.items():
        have = state[name]
        if have.shape != want.shape or have.is_floating_point() != want.is_floating_point() or have.is_complex():
            raise InputFileError(path, f"its {what} weight {name} is {have.dtype} {tuple(have.shape)}, "
                                       f"its config needs {want.dtype} {tuple(want.shape)}")


def teacher_state(payload: dict, average: bool = True) -> dict[str, torch.Tensor]:
    """The teacher's state dict in a checkpoint's payload: the weights' moving average when
    ``average`` and the checkpoint keeps one, else the weights; Module C's part of a joint
    (HyperBones) checkpoint."""
    state = (payload.get("ema") if average else None) or payload["model"]
    if "runtime" in payload["config"]:
        state = {name[len("teacher."):]: value for name, value in state.items() if name.startswith("teacher.")}
    return state


def teacher_from_checkpoint(path, device: str | torch.device = "cpu") -> tuple["Teacher", dict]:
    """The teacher model (eval mode; the weights' moving average when the checkpoint keeps
    one) and the checkpoint's payload. A joint (HyperBones) checkpoint gives its Module C."""
    from hyperbones.models.teacher import Teacher, TrunkConfig  # the teacher's graph code: only when asked for

    payload = load_checkpoint(path, map_location=device)
    config = _model_config(Path(path), payload, "model", TrunkConfig)
    state = teacher_state(payload)
    _check_state(Path(path), lambda: Teacher(config), state, "teacher")
    model = Teacher(config).to(device)
    model.load_state_dict(state)
    model.eval()
    return model, payload


def hyperbones_payload(path=None, device: str | torch.device = "cpu", whole: bool = True) -> dict:
    """A HyperBones checkpoint's payload (default: the shipped model), refusing a teacher's and
    one whose weights do not fit its config (so ``model_of`` can build it). ``whole`` False
    checks Module A's part alone, without importing the teacher (Warp)."""
    if path is None:
        if not SHIPPED_HYPERBONES.exists():
            raise ParameterError("no trained HyperBones model ships with this version yet: train one with "
                                 "`hyperbones train --config configs/hyperbones-small.toml` and pass --checkpoint FILE")
        path = SHIPPED_HYPERBONES
    payload = load_checkpoint(path, map_location=device)
    if "runtime" not in payload["config"]:
        raise InputFileError(path, "a teacher checkpoint, not a HyperBones one (its config has no [runtime] table)")
    path = Path(path)
    runtime = _model_config(path, payload, "runtime", ModuleAConfig)
    state = payload.get("ema") or payload["model"]
    if whole:
        from hyperbones.models.hyperbones import HyperBonesConfig, HyperBonesModel
        from hyperbones.models.teacher import TrunkConfig

        config = HyperBonesConfig(_model_config(path, payload, "model", TrunkConfig), runtime)
        _check_state(path, lambda: HyperBonesModel(config), state, "HyperBones")
    else:
        _check_state(path, lambda: ModuleA(runtime), _module_a_state(state), "Module A")
    return payload


def _module_a_state(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {name[len("runtime."):]: value for name, value in state.items() if name.startswith("runtime.")}


def model_of(payload: dict, device: str | torch.device = "cpu"):
    """The ``HyperBonesModel`` (eval mode) of a loaded HyperBones checkpoint payload."""
    from hyperbones.models.hyperbones import HyperBonesModel

    return HyperBonesModel.from_payload(payload).to(device)


def hyperbones_from_checkpoint(path=None, device: str | torch.device = "cpu"):
    """The ``HyperBonesModel`` (eval mode) of a joint training checkpoint or an exported one
    (default: the shipped one). Building it imports the teacher (Warp); ``load_module_a``
    is the light path for Module A alone."""
    return model_of(hyperbones_payload(path, device), device)


def load_module_a(path=None, device: str | torch.device = "cpu") -> ModuleA:
    """Module A alone from a HyperBones checkpoint (all the per-frame runtime needs with
    identity caches; no teacher, Warp or Anny), in eval mode."""
    payload = hyperbones_payload(path, device, whole=False)
    module = ModuleA(ModuleAConfig.from_dict(payload["config"]["runtime"]))
    module.load_state_dict(_module_a_state(payload.get("ema") or payload["model"]))
    return module.to(device).eval()
