"""Which nearest-face search to use: Warp's BVH or its exact torch twin (``TorchProximity``).

On the CPU Warp's BVH is the fastest measured (4–5× the torch search); on a GPU, or where
Warp is not installed (the project's GPU machines), the torch search keeps the query on
torch's device. Both give the same faces up to float32 ties.
"""

from __future__ import annotations

import torch

from hyperbones.errors import ParameterError

SEARCHES = ("auto", "warp", "torch")
SEQUENCE_RANGE = 0.5  # m: ``signed_distances_along``'s search range; farther points get inf


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


def signed_distances_along(search, points: torch.Tensor, bodies: torch.Tensor,
                           max_distance: float = SEQUENCE_RANGE) -> torch.Tensor:
    """(T,N,3) points, (T,Nb,3) bodies -> (T,N) signed distance of each point to its frame's body
    (inf beyond ``max_distance``), with ``search``: any nearest-face search over the bodies'
    faces (Warp's ``BodyProximity``, ``TorchProximity``, a batch's ``BatchedProximity``). One
    refit and one batched query a frame: for whole sequences after the fact (metrics, checks)."""
    distances = []
    for frame in range(points.shape[0]):
        search.update(bodies[frame])
        distances.append(search.query(points[frame], max_distance=max_distance).signed_distance)
    return torch.stack(distances)


__all__ = ["SEARCHES", "SEQUENCE_RANGE", "search_backend", "signed_distances_along"]
