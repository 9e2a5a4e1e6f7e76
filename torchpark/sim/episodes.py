"""Per-episode draws of the paper's procedural lots: the goal slot, which other slots hold
parked cars, and the start pose. Each function takes the env's ``torch.Generator``; the draws
are made for every row (static shapes) and the reset keeps the rows it resets."""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.config import LotConfig, VehicleConfig
from torchpark.sim.geometry import OrientedBoxes
from torchpark.sim.layout import LotLayout, start_pose_valid, uniform_poses


class StartDraw(NamedTuple):
    """Random inputs of :func:`choose_start` for N envs: ``uniform`` (N, K, 3) poses uniform
    over the lot, ``fallback`` (N, 3) one pose from the pre-drawn valid pool."""

    uniform: Tensor
    fallback: Tensor


class LotDraw(NamedTuple):
    """N new lots: ``goal_slot`` (N,) int64, ``occupied`` (N, S) bool (which slots hold a
    parked car), ``occupancy`` (N,) float32 (the occupancy they were drawn with) and ``start``
    the start poses' random inputs."""

    goal_slot: Tensor
    occupied: Tensor
    occupancy: Tensor
    start: StartDraw


def draw_goals_and_cars(num_envs: int, num_slots: int, occupancy: float,
                        generator: torch.Generator, device: torch.device
                        ) -> tuple[Tensor, Tensor]:
    """Goal slot per env and which slots hold a parked car.

    Returns goal (N,) int64 uniform over the slots, and occupied (N, S) bool with exactly
    round_half_up(occupancy * (S - 1)) of the non-goal slots, drawn uniformly, set.
    """
    goal = torch.randint(num_slots, (num_envs,), generator=generator, device=device)
    parked = math.floor(occupancy * (num_slots - 1) + 0.5)
    keys = torch.rand(num_envs, num_slots, generator=generator, device=device)
    # The goal gets the largest key, so it is never among the `parked` smallest.
    keys = keys.scatter(1, goal[:, None], 2.0)
    rank = keys.argsort(dim=1).argsort(dim=1)
    return goal, rank < parked


def draw_starts(num_envs: int, layout: LotLayout, lot: LotConfig, generator: torch.Generator
                ) -> StartDraw:
    """The random draws of one reset's start poses for ``num_envs`` envs."""
    device = layout.slots.device
    pick = torch.randint(layout.start_pool.shape[0], (num_envs,), generator=generator,
                         device=device)
    uniform = uniform_poses(layout, (num_envs, lot.start_candidates), generator)
    return StartDraw(uniform, layout.start_pool[pick])


def draw_lots(num_envs: int, occupancy: float, layout: LotLayout, lot: LotConfig,
              generator: torch.Generator) -> LotDraw:
    """``num_envs`` new lots at ``occupancy``: goals, parked cars, start draws, in that order
    from ``generator``."""
    device = layout.slots.device
    goal, occupied = draw_goals_and_cars(num_envs, layout.num_slots, occupancy, generator,
                                         device)
    start = draw_starts(num_envs, layout, lot, generator)
    return LotDraw(goal, occupied, torch.full((num_envs,), occupancy, device=device), start)


def first_valid(candidates: Tensor, valid: Tensor) -> tuple[Tensor, Tensor]:
    """Each row's first valid candidate (N, 3) of (N, K, 3) and whether it has one (N, 1)."""
    k = candidates.shape[1]
    # Index of the first valid candidate (k - 1 when none is). A masked min rather than
    # argmax: inductor's vectorised argmax over a uint8 mask returned out-of-range indices
    # (torch 2.13, CPU).
    index = torch.arange(k, device=candidates.device)
    first = torch.where(valid, index, k - 1).amin(dim=1)
    chosen = candidates.gather(1, first[:, None, None].expand(-1, 1, 3))[:, 0]
    return chosen, valid.any(dim=1, keepdim=True)


def choose_start(draw: StartDraw, blocked: OrientedBoxes, vehicle: VehicleConfig) -> Tensor:
    """Start poses (N, 3): each env's first valid uniform candidate, else its fallback.

    The fallback comes from the pool of valid poses, so the result is always valid; the work
    is bounded by N x K x B box tests. Conditioned on one uniform candidate being valid, the
    uniform pose is uniform over the valid poses.
    """
    start = draw.fallback
    if draw.uniform.shape[1] > 0:
        chosen, found = first_valid(draw.uniform, start_pose_valid(draw.uniform, blocked,
                                                                   vehicle))
        start = torch.where(found, chosen, start)
    return start
