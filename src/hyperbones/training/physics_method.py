"""A reference physics solver as a simulation method: each frame minimises the incremental
potential that the teacher trains on (``training.loss.physics_terms``: StVK stretching,
bending, gravity, inertia, body collision at the ramp's final weight, friction) over the
free vertices with L-BFGS, starting from the explicit guess x(t) + v(t).

This is backward-Euler cloth by optimisation, as HOOD's self-supervision implies. It is
slow (hundreds of energy evaluations per frame) and meant as the teacher's accuracy
reference in ``hyperbones eval``, not for production. It shares the teacher's rollout
(``runtime.teacher_rollout.StepRollout``: the settling step, strain limiting and contact after
every step), so the two differ only in how each step is found.
"""

from __future__ import annotations

from pathlib import Path

import torch

from hyperbones.body.anny_body import Body
from hyperbones.devices import pick_device
from hyperbones.garment.garment import Garment
from hyperbones.physics.material import Material
from hyperbones.runtime.teacher_rollout import StepRollout
from hyperbones.training.config import DataConfig, TrainConfig
from hyperbones.training.loss import physics_terms

SOLVER_ITERATIONS = 200  # L-BFGS iterations per frame; the energy still falls a little past 100


class PhysicsMethod(StepRollout):
    """Garment positions from minimising each frame's incremental potential (no network)."""

    name = "physics"

    def __init__(self, garment: Garment, body: Body, rest_vertices: torch.Tensor, material: Material | None = None,
                 checkpoint: str | Path | None = None, device: str = "auto", progress: bool = False,
                 iterations: int = SOLVER_ITERATIONS):
        """``checkpoint`` is accepted for the METHODS signature and ignored (nothing is learnt)."""
        self.device = pick_device(device)
        self.iterations = int(iterations)
        self.settle_dt = DataConfig().settle_dt
        self.collision_weight = TrainConfig().collision_weight_end
        self._prepare_cloth(garment, body, rest_vertices, material or garment.material, progress)

    def _step(self, positions, velocities, pinned_next, body_now, body_next, nearest, dt):
        guess = torch.where(self.movable[:, None], positions + velocities, pinned_next)
        following = self._minimise(guess, positions, velocities, nearest, body_now, body_next, dt)
        return following, following - positions

    def _minimise(self, guess: torch.Tensor, positions: torch.Tensor, velocities: torch.Tensor, nearest,
                  body_now: torch.Tensor, body_next: torch.Tensor, dt: float) -> torch.Tensor:
        """(V,3) x(t+1) minimising the step's energy over the free vertices, from ``guess``."""
        free = guess[self.movable].clone().requires_grad_(True)
        optimiser = torch.optim.LBFGS([free], max_iter=self.iterations, history_size=20,
                                      line_search_fn="strong_wolfe", tolerance_grad=1e-9, tolerance_change=1e-12)

        def step_energy() -> torch.Tensor:
            candidate = guess.clone()
            candidate[self.movable] = free
            terms = physics_terms(candidate, positions, velocities, self.rest, nearest, body_now, body_next,
                                  self.body_faces, self.collision_weight, dt)
            return sum(terms.values())

        def closure() -> torch.Tensor:
            optimiser.zero_grad()
            energy = step_energy()
            energy.backward()
            return energy

        with torch.enable_grad():
            optimiser.step(closure)
        result = guess.clone()
        result[self.movable] = free.detach()
        return result
