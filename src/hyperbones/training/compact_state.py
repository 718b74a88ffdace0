"""A resumable training state small enough to travel: shards under 15 MiB, compact moments.

The GPU machines take at most 64 MiB with a job and give back files of at most 16 MiB, and
the project commits the active run's state so the next GPU job resumes it. So this state
keeps the model in float32 (exact), the weights' moving average as its bfloat16 difference
from the model (entries equal to the model's are left out), and Adam's moments in bfloat16:
a teacher at the paper's size (12 MB of weights) then needs 30 MB instead of 49. Tensors are
cut into shards of at most ``SHARD_BYTES``; ``index.pt``, written last and atomically, names
the shards of the latest step, so a save killed part way leaves the previous state whole.

    save_compact_state(folder, model, ema, optimizer, step, config)
    model, ema, optimizer, step, config = load_compact_state(folder)
"""

from __future__ import annotations

from pathlib import Path

import torch

from hyperbones.errors import InputFileError
from hyperbones.io_utils import atomic_path, load_versioned

STATE_VERSION = 1
SHARD_BYTES = 15 * 2**20
INDEX = "index.pt"


def _flatten(tree, prefix: str, out: dict) -> object:
    """Tensors of a nested dict/list replaced by keys into ``out``; the rest kept as it is."""
    if isinstance(tree, torch.Tensor):
        out[prefix] = tree
        return {"__tensor__": prefix}
    if isinstance(tree, dict):
        return {key: _flatten(value, f"{prefix}/{key}", out) for key, value in tree.items()}
    if isinstance(tree, (list, tuple)):
        return [_flatten(value, f"{prefix}/{index}", out) for index, value in enumerate(tree)]
    return tree


def _unflatten(tree, tensors: dict):
    if isinstance(tree, dict):
        if set(tree) == {"__tensor__"}:
            return tensors[tree["__tensor__"]]
        return {key: _unflatten(value, tensors) for key, value in tree.items()}
    if isinstance(tree, list):
        return [_unflatten(value, tensors) for value in tree]
    return tree


def save_compact_state(folder: str | Path, model: dict, ema: dict, optimizer: dict, step: int,
                       config: dict) -> list[Path]:
    """Write the state of ``step`` into ``folder`` (shards, then the index); returns the files now there."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tensors: dict[str, torch.Tensor] = {}
    layout = {
        "model": _flatten({name: value.detach() for name, value in model.items()}, "model", tensors),
        "ema": _flatten({name: (value.detach() - model[name].detach()).to(torch.bfloat16)
                         for name, value in ema.items()
                         if value.is_floating_point() and not torch.equal(value, model[name])}, "ema", tensors),
        "optimizer": _flatten(_compact_optimizer(optimizer), "optimizer", tensors),
    }
    shards, current, size = [], {}, 0
    for name, value in tensors.items():
        value = value.cpu().contiguous()
        nbytes = value.numel() * value.element_size()
        if current and size + nbytes > SHARD_BYTES:
            shards.append(current)
            current, size = {}, 0
        current[name] = value
        size += nbytes
    shards.append(current)
    names = []
    for index, shard in enumerate(shards):
        path = folder / f"state-{step}-{index}.pt"
        with atomic_path(path) as tmp:
            torch.save(shard, tmp)
        names.append(path.name)
    with atomic_path(folder / INDEX) as tmp:
        torch.save({"version": STATE_VERSION, "step": step, "config": config, "layout": layout, "shards": names}, tmp)
    for stale in folder.glob("state-*.pt"):
        if stale.name not in names:
            stale.unlink(missing_ok=True)
    return sorted(folder.iterdir())


def _compact_optimizer(state: dict) -> dict:
    """Adam's state with its moments in bfloat16 (its step counters as they are)."""
    moments = {}
    for key, slot in state["state"].items():
        moments[key] = {name: value.to(torch.bfloat16) if name.startswith("exp_avg") else value
                        for name, value in slot.items()}
    return {"state": moments, "param_groups": state["param_groups"]}


def has_compact_state(folder: str | Path) -> bool:
    return (Path(folder) / INDEX).exists()


def load_compact_state(folder: str | Path, device: str | torch.device = "cpu"
                       ) -> tuple[dict, dict, dict, int, dict]:
    """(model, moving average, optimiser state, step, config) from ``folder``; the average and
    moments back in float32. A missing or damaged file is an ``InputFileError`` naming it."""
    folder = Path(folder)
    index = load_versioned(folder / INDEX, "training state index", STATE_VERSION)
    tensors = {}
    for name in index["shards"]:
        path = folder / name
        if not path.exists():
            raise InputFileError(path, "missing: the state index names it (copy the whole state folder)")
        try:
            tensors.update(torch.load(path, map_location=device, weights_only=True))
        except Exception as error:  # noqa: BLE001 - torch raises many kinds for a bad file
            raise InputFileError(path, f"not a training state shard ({type(error).__name__})") from None
    try:
        layout = index["layout"]
        model = _unflatten(layout["model"], tensors)
        differences = _unflatten(layout["ema"], tensors)
        optimizer = _unflatten(layout["optimizer"], tensors)
    except KeyError as error:
        raise InputFileError(folder / INDEX, f"names a tensor no shard holds ({error})") from None
    ema = {name: (value + differences[name].float()) if name in differences else value.clone()
           for name, value in model.items()}
    for slot in optimizer["state"].values():
        for name in list(slot):
            if name.startswith("exp_avg"):
                slot[name] = slot[name].float()
    return model, ema, optimizer, int(index["step"]), index["config"]


__all__ = ["has_compact_state", "load_compact_state", "save_compact_state"]
