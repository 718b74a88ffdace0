"""Feature normalisation with statistics gathered during the first training batches."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch
from torch import nn


class Normalizer(nn.Module):
    """(…,F) -> (…,F) standardised by a running mean and std.

    While training, each forward adds its batch to the statistics until
    ``max_accumulations`` batches have been seen (MeshGraphNets keeps accumulating for most
    of training: states seen late in training, such as long rollouts, differ from early
    ones); after that, and in eval mode, they are fixed. A batch with a non-finite value (or
    one whose square overflows) is left out, so one blown-up state cannot poison them. The
    statistics are buffers, so they are saved in checkpoints (and DDP keeps the replicas
    equal by broadcasting them from rank 0).
    """

    def __init__(self, size: int, max_accumulations: int = 100_000, std_epsilon: float = 1e-2):
        super().__init__()
        self.max_accumulations = max_accumulations
        self.std_epsilon = std_epsilon
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("batches", torch.zeros((), dtype=torch.float64))
        self.register_buffer("sum", torch.zeros(size, dtype=torch.float64))
        self.register_buffer("sum_squares", torch.zeros(size, dtype=torch.float64))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        if self.training and self.batches < self.max_accumulations and features.shape[0] > 0:
            flat = features.detach().reshape(-1, features.shape[-1]).double()
            if not bool(torch.isfinite(flat.square().sum(0)).all()):
                return (features - self.mean.to(features)) / self.std.to(features)  # a blown-up state: not counted
            self.count += flat.shape[0]
            self.batches += 1
            self.sum += flat.sum(0)
            self.sum_squares += flat.square().sum(0)
        return (features - self.mean.to(features)) / self.std.to(features)

    @property
    def mean(self) -> torch.Tensor:
        return self.sum / self.count.clamp_min(1)

    @property
    def std(self) -> torch.Tensor:
        variance = self.sum_squares / self.count.clamp_min(1) - self.mean.square()
        return variance.clamp_min(0).sqrt().clamp_min(self.std_epsilon)


@contextmanager
def frozen_statistics(module: nn.Module) -> Iterator[None]:
    """Within the block, the ``Normalizer``s inside ``module`` use their statistics without
    adding to them (inputs that are not the states they describe, e.g. Module B's canonical
    graphs through the teacher's trunk); the rest of the module keeps its mode."""
    gathering = [child for child in module.modules() if isinstance(child, Normalizer) and child.training]
    for child in gathering:
        child.eval()
    try:
        yield
    finally:
        for child in gathering:
            child.train()
