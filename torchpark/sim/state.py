"""The types the paper's step passes around: the per-env state and what one step emits
(NamedTuples of [N, ...] tensors), apart from the functions that make them, so that the step,
the observation and the aids all read them without importing each other."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor


class ParkingState(NamedTuple):
    """Per-env state of the paper's task.

    pose (N, 3) rear axle (x m, y m, psi rad); speed (N,) m/s; goal_slot (N,) int64; goal
    (N, 3) its goal pose; present (N, M) float32, 1 where the obstacle exists (a parked car in
    that slot; walls always), else 0; steps (N,) int64 steps of dt taken this episode;
    occupancy (N,) float32 the lot was drawn with. ``present`` is float, not bool: compiled
    kernels loaded bool masks with branches that a random occupancy pattern mispredicted
    (45% slower).
    """

    pose: Tensor
    speed: Tensor
    goal_slot: Tensor
    goal: Tensor
    present: Tensor
    steps: Tensor
    occupancy: Tensor

    @classmethod
    def zeros(cls, num_envs: int, num_obstacles: int, device: torch.device | str
              ) -> ParkingState:
        """A state of ``num_envs`` rows holding no lot (every field zero)."""
        n = num_envs
        return cls(
            pose=torch.zeros(n, 3, device=device),
            speed=torch.zeros(n, device=device),
            goal_slot=torch.zeros(n, dtype=torch.int64, device=device),
            goal=torch.zeros(n, 3, device=device),
            present=torch.zeros(n, num_obstacles, device=device),
            steps=torch.zeros(n, dtype=torch.int64, device=device),
            occupancy=torch.zeros(n, device=device),
        )


class StepResult(NamedTuple):
    """What one step emits; all (N, 1) except observation (N, NAV_DIM + n_rays) float32.
    cost: the paper's C after the step (float32), what the success test compares."""

    observation: Tensor
    reward: Tensor
    terminated: Tensor
    truncated: Tensor
    done: Tensor
    success: Tensor
    collision: Tensor
    cost: Tensor
