"""Checkpoints: atomic writes, safe loads (``weights_only=True``), and the shipped teacher.

A training checkpoint holds the model state, the weights' moving average (only the entries
that differ from the model's: a frozen part's average is its weights), the step and the
config (as a plain dict); the optimiser's state sits beside it in ``optimizer.pt`` (older
checkpoints hold it inside), so neither file outgrows the repository's file limit. A save can
be killed at any moment and still resume: the optimiser state of the new step is written as
``optimizer.<step>.pt`` first, the checkpoint replaced next, and only then is it renamed to
``optimizer.pt``; the pair the checkpoint names is on disk at every moment between. A resumed
run re-seeds its episode sampler from the step, so it does not replay the episodes it has
already seen. ``export_weights`` keeps what inference needs
(model state + config + a training summary) for committing.
"""

from __future__ import annotations

import glob
import os
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.io_utils import atomic_path
from hyperbones.models.loading import load_checkpoint, save_checkpoint

if TYPE_CHECKING:
    from hyperbones.runtime.config import RuntimeConfig


def optimizer_path(checkpoint: str | Path, step: int | None = None) -> Path:
    """Where a training checkpoint's optimiser state is kept: ``optimizer.pt`` beside it; with
    ``step``, where a save stages that step's state until the checkpoint is replaced
    (``optimizer.<step>.pt``)."""
    return Path(checkpoint).with_name("optimizer.pt" if step is None else f"optimizer.{step}.pt")


def save_training_state(path: str | Path, model: dict, ema: dict, optimizer: dict, step: int, config: dict) -> Path:
    """Write a resumable training state: the optimiser's, staged (``optimizer_path(path, step)``),
    then the checkpoint, each atomically, then the staged state renamed to ``optimizer.pt``;
    the moving average keeps only entries that differ from the model. What killed saves left
    (temporary files, states staged for steps never reached) is removed at the end."""
    path = Path(path)
    staged = save_checkpoint(optimizer_path(path, step), {"optimizer": optimizer, "step": step})
    changed = {name: value for name, value in ema.items() if not torch.equal(value, model[name])}
    try:
        save_checkpoint(path, {"model": model, "ema": changed, "step": step, "config": config})
    except BaseException:
        staged.unlink(missing_ok=True)  # the checkpoint stays at its last step, with that step's state
        raise
    os.replace(staged, optimizer_path(path))
    _remove_leftovers(path)
    return path


def _remove_leftovers(path: Path) -> None:
    """Staged optimiser states (``optimizer.<step>.pt``) and ``atomic_path``'s temporary files
    (``.<stem>.<hex>.tmp<suffix>``) of checkpoint ``path`` and its optimiser state, left by saves
    killed part way. Only the run's one writer (rank 0) saves, so none is being written now."""
    kept = optimizer_path(path)
    staged = [file for file in path.parent.glob(f"{kept.stem}.*{kept.suffix}")
              if file.name[len(kept.stem) + 1:-len(kept.suffix)].isdigit()]
    temporary = [*path.parent.glob(f".{kept.stem}.*.tmp{kept.suffix}"),
                 *path.parent.glob(f".{glob.escape(path.stem)}.*.tmp{glob.escape(path.suffix)}")]
    for leftover in staged + temporary:
        leftover.unlink(missing_ok=True)


def load_optimizer_state(path: str | Path, payload: dict, map_location: str | torch.device = "cpu") -> dict:
    """The optimiser state for checkpoint ``path`` whose ``payload`` is loaded: inside it
    (older checkpoints), else from ``optimizer_path``, which must be from the same step; a save
    killed between replacing the checkpoint and renaming its staged state leaves that state
    under ``optimizer_path(path, step)``."""
    if "optimizer" in payload:
        return payload["optimizer"]
    state_path = optimizer_path(path, payload["step"])
    if not state_path.exists():
        state_path = optimizer_path(path)
    if not state_path.exists():
        raise InputFileError(state_path, "missing: --resume needs the optimiser state saved beside the checkpoint")
    try:
        state = torch.load(state_path, map_location=map_location, weights_only=True)
    except Exception as error:  # noqa: BLE001
        raise InputFileError(state_path, f"not an optimiser state ({type(error).__name__})") from None
    if not isinstance(state, dict) or state.get("step") != payload["step"]:
        raise InputFileError(state_path, f"from step {state.get('step') if isinstance(state, dict) else '?'}, "
                                         f"but the checkpoint is at step {payload['step']} (interrupted save?)")
    return state["optimizer"]


def export_weights(checkpoint: str | Path, out: str | Path, summary: str | Path | None = None,
                   runtime_from: str | Path | None = None, runtime: str | None = None,
                   summary_from: str | Path | None = None) -> Path:
    """Write the inference part of a training checkpoint (the weights' moving average when it
    keeps one, else the model; config, step) to ``out``, and ``summary`` (default: ``<out>.md``): the
    config, and when the checkpoint's folder has a TensorBoard log, the wall time of training
    and a summary of the log, both up to the checkpoint's step. A HyperBones model also keeps
    the ``RuntimeConfig`` it is meant to run with (``export_runtime_config``: by default the
    checkpoint's, else the shipped model's), written into the summary too.

    ``checkpoint`` may be an exported HyperBones model itself: exported again, its weights,
    config and step stay as they are and only the runtime settings change; the training part of
    its own summary (``summary_from``, default ``<checkpoint>.md``) is carried over."""
    from hyperbones.training.summary import read_log, training_seconds, training_summary

    payload = load_checkpoint(checkpoint)
    slim = {"model": payload.get("ema") or payload["model"], "config": payload["config"], "step": payload["step"]}
    runtime_text = ""
    if "runtime" in payload["config"]:  # a HyperBones model: the runtime settings it ships with
        settings, source = export_runtime_config(payload, checkpoint, runtime_from, runtime)
        slim["runtime_config"] = settings.as_dict()
        runtime_text = f"Runtime settings stored with it ({source}):\n\n```\n{_config_text(settings.as_dict())}```\n\n"
    elif runtime_from is not None or runtime:
        raise ParameterError(f"{checkpoint}: a teacher has no runtime settings (--runtime-from, --runtime are for "
                             "a HyperBones model)")
    # An exported model (export's own output: no moving average kept, runtime settings stored)
    # has no log of its own beside it; its summary records its training.
    exported = "ema" not in payload and "runtime_config" in payload
    log_dir = Path(checkpoint).parent / "tensorboard"
    if exported:
        text = _carried_training_text(checkpoint, summary_from)
    elif summary_from is not None:
        raise ParameterError(f"{checkpoint}: --summary-from is for an exported HyperBones model, not a run's checkpoint")
    elif log_dir.exists():
        log = read_log(log_dir)
        hours = training_seconds(log, up_to=payload["step"]) / 3600
        text = (f"Training took {hours:.1f} h of wall-clock time to this step (the gaps between logged steps; "
                f"pauses over 10 minutes left out).\n\nTraining log (medians per stretch of steps):\n\n"
                f"{training_summary(log, up_to=payload['step'])}\n")
    else:
        text = f"{_TRAINING_TEXT_STARTS[1]}\n"
    out = save_checkpoint(out, slim)
    parameters = sum(v.numel() for v in payload["model"].values() if hasattr(v, "numel"))
    with atomic_path(Path(summary) if summary else out.with_suffix(".md")) as tmp:
        tmp.write_text(f"# {out.name}\n\nStep {payload['step']}, {parameters:,} numbers in the state dict. "
                       f"Config (saved in the checkpoint):\n\n```\n{_config_text(payload['config'])}```\n\n{runtime_text}{text}")
    return out


# Where the training part of an export's summary starts (``export_weights`` writes one of the two).
_TRAINING_TEXT_STARTS = ("Training took ", "(no TensorBoard log beside the checkpoint)")


def _carried_training_text(checkpoint: str | Path, summary_from: str | Path | None) -> str:
    """The training part of an exported model's summary, taken from its own summary
    (``summary_from``, default ``<checkpoint>.md`` when there is one), so a model exported again
    with other runtime settings keeps the record of its training."""
    source = Path(summary_from) if summary_from is not None else Path(checkpoint).with_suffix(".md")
    if not source.is_file():
        if summary_from is not None:
            raise InputFileError(source, "missing (--summary-from: the summary of the model exported again)")
        return f"{_TRAINING_TEXT_STARTS[1]}\n"
    text = source.read_text(encoding="utf-8", errors="replace")
    starts = [index for index in (text.find(marker) for marker in _TRAINING_TEXT_STARTS) if index >= 0]
    if not starts:
        raise InputFileError(source, "holds no training summary (not one that hyperbones export wrote)")
    return (f"Exported from {checkpoint}, itself an export (weights, config and step unchanged); its "
            f"training as {source} records it:\n\n{text[min(starts):]}")


def export_runtime_config(payload: dict, checkpoint: str | Path, runtime_from: str | Path | None = None,
                          runtime: str | None = None) -> tuple[RuntimeConfig, str]:
    """The runtime settings an exported HyperBones model stores, and where they came from (for the
    summary): those of ``runtime_from`` (an exported model, or ``"defaults"`` for
    ``RuntimeConfig()``), else the checkpoint's own, else (a training checkpoint stores none) the
    shipped model's, as ``runtime_config_of`` reads it; then ``runtime`` (``key=value,...``) over them."""
    from hyperbones.runtime.config import RuntimeConfig
    from hyperbones.runtime.simulator import runtime_config_in, runtime_config_of

    if runtime_from == "defaults":
        settings, source = RuntimeConfig(), "the defaults of RuntimeConfig"
    elif runtime_from is not None:
        settings, source = runtime_config_in(runtime_from), f"those of {runtime_from}"
        if settings is None:
            raise InputFileError(runtime_from, "stores no runtime settings (not an exported HyperBones model)")
    else:  # a training checkpoint stores none: runtime_config_of gives it the shipped model's
        settings = runtime_config_of(payload, checkpoint)
        source = f"those {checkpoint} stores" if payload.get("runtime_config") is not None else "the shipped model's"
    if runtime:
        settings, source = settings.with_overrides(runtime), f"{source}, with {runtime}"
    return settings, source


def _config_text(config: dict, prefix: str = "") -> str:
    lines = []
    for key, value in config.items():
        if isinstance(value, dict) and prefix == "":
            lines.append(f"[{key}]")
            lines.append(_config_text(value, key).rstrip("\n"))
        else:
            lines.append(f"{key} = {value!r}")
    return "\n".join(lines) + "\n"
