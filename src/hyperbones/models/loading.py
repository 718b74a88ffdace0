"""Loading trained models: checkpoints written atomically and read without executing pickled
code, the shipped teacher and HyperBones model, and the models built from them."""

from __future__ import annotations

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

MAX_MODEL_SIZE = 4096
"""Largest size a checkpoint's model config may state (a width, a block or bone count, a UV
resolution): larger ones are damage, and would build an enormous model before any check."""


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Load a checkpoint without executing pickled code; one-line errors name the file."""
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
    if payload.get("ema"):
        payload["ema"] = {**payload["model"], **payload["ema"]}  # entries left out equal the model's
    return payload


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
