"""Per-episode draws of the paper's procedural lots: the goal slot, which other slots hold
parked cars, and the start pose. The random numbers are drawn from the env's
``torch.Generator`` for the episodes the env draws ahead (:func:`draw_lots`, eager: a compiled
graph cannot take a generator); what is made of them (:func:`occupied_slots`,
:func:`choose_start`) is pure tensor work, compiled with the batched draw."""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.config import LotConfig, VehicleConfig
from torchpark.sim.geometry import OrientedBoxes
from torchpark.sim.layout import LotLayout, lot_poses, start_pose_valid


class StartDraw(NamedTuple):
    """Random inputs of :func:`choose_start` for B rows: ``unit`` (B, K, 3) uniform in
    [0, 1) (K uniform candidate poses, scaled to the lot by :func:`choose_start`), ``pick``
    (B,) int64 a uniform index into the lot's pool of valid starts (the fallback)."""

    unit: Tensor
    pick: Tensor


class LotDraw(NamedTuple):
    """Random inputs of B new lots: ``goal_slot`` (B,) int64 uniform over the slots;
    ``keys`` (B, S) float32 uniform in [0, 1), whose ``parked`` (B,) int64 smallest among the
    non-goal slots hold a parked car; ``occupancy`` (B,) float32 the occupancy they were
    drawn with; ``start`` the start poses' random inputs."""

    goal_slot: Tensor
    keys: Tensor
    parked: Tensor
    occupancy: Tensor
    start: StartDraw


def parked_cars(occupancy: float, num_slots: int) -> int:
    """The number of parked cars at ``occupancy``: round_half_up(occupancy * (S - 1)), in
    float64 (the spec's count, whatever the device's float32 rounding)."""
    return math.floor(occupancy * (num_slots - 1) + 0.5)


def draw_lots(num_envs: int, occupancy: float, layout: LotLayout, lot: LotConfig,
              generator: torch.Generator) -> LotDraw:
    """The random inputs of ``num_envs`` new lots at ``occupancy``: goals, car keys, start
    candidates and fallback picks, in that order from ``generator``."""
    device = layout.slots.device
    n, s = num_envs, layout.num_slots
    goal = torch.randint(s, (n,), generator=generator, device=device)
    keys = torch.rand(n, s, generator=generator, device=device)
    pick = torch.randint(layout.start_pool.shape[0], (n,), generator=generator, device=device)
    unit = torch.rand(n, lot.start_candidates, 3, generator=generator, device=device)
    return LotDraw(goal, keys, torch.full((n,), parked_cars(occupancy, s), device=device),
                   torch.full((n,), occupancy, device=device), StartDraw(unit, pick))


def occupied_slots(goal_slot: Tensor, keys: Tensor, parked: Tensor) -> Tensor:
    """Which slots hold a parked car, (B, S) bool: the ``parked`` (B,) non-goal slots with
    the smallest ``keys`` (B, S) float32 in [0, 1), ties broken by the slot's index, so
    exactly ``parked`` of them, a uniform subset.

    A non-negative float's bit pattern, read as an integer, orders as its value, so
    (bits x S + slot) orders the slots by (key, index) and every value is distinct: the
    slots at or below the row's ``parked``-th smallest are those. One sort of S values per
    row (a pairwise rank of every slot against every other cost 3x as much, compiled).
    """
    s = keys.shape[1]
    slots = torch.arange(s, device=keys.device)
    # The goal's key is above every other, so it is never among the `parked` smallest.
    keys = torch.where(slots == goal_slot[:, None], 2.0, keys)
    order = keys.contiguous().view(torch.int32).to(torch.int64) * s + slots
    last = order.sort(dim=1).values.gather(1, (parked - 1).clamp(min=0)[:, None])
    return (order <= last) & (parked[:, None] > 0)


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


def choose_start(draw: StartDraw, extent: Tensor, pool: Tensor, blocked: OrientedBoxes,
                 vehicle: VehicleConfig) -> Tensor:
    """Start poses (B, 3): each row's first valid uniform candidate (rear axle uniform over
    the lot [0, width] x [0, height], ``extent`` (2,), heading uniform in [-pi, pi)), else its
    fallback from ``pool`` (P, 3) of valid poses.

    The result is always valid; the work is bounded by B x K x (S + 4) box tests.
    Conditioned on one uniform candidate being valid, the pose is uniform over the valid
    poses (and the pool is a uniform sample of them).
    """
    start = pool[draw.pick]
    if draw.unit.shape[1] > 0:
        uniform = lot_poses(draw.unit, extent)
        chosen, found = first_valid(uniform, start_pose_valid(uniform, blocked, vehicle))
        start = torch.where(found, chosen, start)
    return start
