"""Loading trained models: checkpoints written atomically and read without executing pickled
code, the shipped teacher and HyperBones model, and the models built from them."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

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
        raise InputFileError(path, f"not a hyperbones checkpoint ({type(error).__name__}: {str(error).splitlines()[0]})") from None
    if not isinstance(payload, dict) or "model" not in payload or "config" not in payload:
        raise InputFileError(path, "not a hyperbones checkpoint (no model state or config)")
    if payload.get("ema"):
        payload["ema"] = {**payload["model"], **payload["ema"]}  # entries left out equal the model's
    return payload


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
    model = Teacher(TrunkConfig(**payload["config"]["model"])).to(device)
    model.load_state_dict(teacher_state(payload))
    model.eval()
    return model, payload


def hyperbones_payload(path=None, device: str | torch.device = "cpu") -> dict:
    """A HyperBones checkpoint's payload (default: the shipped model), refusing a teacher's."""
    if path is None:
        if not SHIPPED_HYPERBONES.exists():
            raise ParameterError("no trained HyperBones model ships with this version yet: train one with "
                                 "`hyperbones train --config configs/hyperbones-small.toml` and pass --checkpoint FILE")
        path = SHIPPED_HYPERBONES
    payload = load_checkpoint(path, map_location=device)
    if "runtime" not in payload["config"]:
        raise InputFileError(path, "a teacher checkpoint, not a HyperBones one (its config has no [runtime] table)")
    return payload


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
    payload = hyperbones_payload(path, device)
    module = ModuleA(ModuleAConfig.from_dict(payload["config"]["runtime"]))
    state = payload.get("ema") or payload["model"]
    module.load_state_dict({name[len("runtime."):]: value for name, value in state.items()
                            if name.startswith("runtime.")})
    return module.to(device).eval()
