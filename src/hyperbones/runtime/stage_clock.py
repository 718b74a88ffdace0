"""Wall time per stage of the per-frame runtime, for ``hyperbones bench --profile``.

The runtime's steps (forward kinematics, Bone-Net, skinning, the UV stage, follow, contact,
projection) each run inside ``clock.stage(name)``; a ``StageClock`` adds up their times over
the frames it sees (CUDA work synchronised before each reading, so a stage is charged for
its own kernels), and ``NO_CLOCK`` costs nothing when no profile is asked for.
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager, nullcontext

import torch

STAGES = ("forward kinematics", "Bone-Net", "garment skinning", "UV raster", "Conv-MLP", "UV sampling", "follow",
          "contact queries", "untangling", "projection", "proxy sweeps")
"""The stages in the order a frame runs them (a table lists them in this order). Posing the
body is not one: the caller poses it (``Body.pose``, ``BodyRig.pose``) and hands it to ``step``."""


class StageClock:
    """Milliseconds per stage, summed over frames; ``frames`` counts ``frame()`` calls."""

    def __init__(self, device: torch.device | str = "cpu"):
        self.device = torch.device(device)
        self.total_ms: dict[str, float] = defaultdict(float)
        self.frames = 0

    def _sync(self) -> None:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)

    @contextmanager
    def stage(self, name: str):
        """Charge the time inside the block to ``name`` (one of ``STAGES``)."""
        if name not in STAGES:
            raise ValueError(f"unknown runtime stage {name!r}; stages: {', '.join(STAGES)}")
        self._sync()
        start = time.perf_counter()
        try:
            yield
        finally:
            self._sync()
            self.total_ms[name] += 1000.0 * (time.perf_counter() - start)

    def frame(self) -> None:
        """One more frame was timed."""
        self.frames += 1

    def reset(self) -> None:
        self.total_ms.clear()
        self.frames = 0

    def per_frame(self) -> dict[str, float]:
        """{stage: mean ms per frame} for the stages that ran, in ``STAGES`` order."""
        frames = max(self.frames, 1)
        return {name: self.total_ms[name] / frames for name in STAGES if name in self.total_ms}


class _NoClock:
    """A clock that times nothing (the default: a frame pays one attribute lookup a stage)."""

    def stage(self, name: str):
        return nullcontext()

    def frame(self) -> None:
        pass


NO_CLOCK = _NoClock()
