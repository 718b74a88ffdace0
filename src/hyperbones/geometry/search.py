"""Which nearest-face search to use: Warp's BVH or its exact torch twin (``TorchProximity``).

On the CPU Warp's BVH is the fastest measured (4–5× the torch search); on a GPU, or where
Warp is not installed (the project's GPU machines), the torch search keeps the query on
torch's device. Both give the same faces up to float32 ties.
"""

from __future__ import annotations

import torch

from hyperbones.errors import ParameterError

SEARCHES = ("auto", "warp", "torch")


def search_backend(search: str, device: str | torch.device) -> str:
    """The nearest-face search to use: ``search`` as asked, or for "auto" Warp's BVH on the CPU
    when Warp is installed (the fastest measured there) and the torch search otherwise."""
    if search not in SEARCHES:
        raise ParameterError(f"contact search must be one of {', '.join(SEARCHES)}, got {search!r}")
    if search != "auto":
        return search
    if torch.device(device).type != "cpu":
        return "torch"
    import importlib.util

    try:
        return "warp" if importlib.util.find_spec("warp") is not None else "torch"
    except ValueError:  # warp blocked in sys.modules (set to None)
        return "torch"


__all__ = ["SEARCHES", "search_backend"]
