"""An emergency brake under the policy: a step of dt that would end in a collision (or, with
a margin, within that much of an obstacle) is not taken (or, with ``steer_clear``, is steered
clear of it), so no collision can happen."""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.aids.config import BrakeConfig
from torchpark.config import ParkingConfig, VehicleConfig
from torchpark.sim.geometry import OrientedBoxes, separation
from torchpark.sim.records import replace
from torchpark.sim.step import move
from torchpark.sim.vehicle import vehicle_obb
from torchpark.sim.world import World, touches_obstacle

_BLOCKED = 1e3  # rad added to a blocked steering angle's distance from the commanded one


class Braking(NamedTuple):
    """One step of dt after the brake, fields (N,) unless stated: ``pose`` (N, 3) and
    ``speed`` m/s where it ends; ``steer`` rad, the steering angle taken (the commanded one
    unless steered clear); ``braked``: the brake stopped it (the car kept its pose at speed
    0); ``intervened``: the brake stopped or steered it."""

    pose: Tensor
    speed: Tensor
    steer: Tensor
    braked: Tensor
    intervened: Tensor


def steer_angles(cfg: ParkingConfig, brake: BrakeConfig, device: torch.device | str | None = None
                 ) -> Tensor:
    """The (K,) steering angles the brake tries, rad: ``brake.steer_clear`` evenly spread
    over [-max_steer, max_steer] (empty when 0)."""
    return torch.linspace(-cfg.vehicle.max_steer, cfg.vehicle.max_steer, brake.steer_clear,
                          device=device)


def fence(pose: Tensor, vehicle: VehicleConfig, margin: float) -> OrientedBoxes:
    """The vehicle's boxes at rear-axle poses [..., 3], grown by ``margin`` m on every side
    (same centre and heading): what the brake keeps clear with ``BrakeConfig.margin``."""
    box = vehicle_obb(pose, vehicle)
    return replace(box, half_length=box.half_length + margin,
                   half_width=box.half_width + margin)


def goal_room(world: World, vehicle: VehicleConfig, margin: float = 0.0) -> float:
    """The smallest gap, m, between the box grown by ``margin`` (:func:`fence`) at any
    slot's goal pose and the walls and the other slots' cars, all parked: the room the lot
    leaves a parked car (0.5 m in the paper's lot). A margin whose gap is not above 0 would
    stop every docking at such a slot."""
    ego = fence(world.goal_poses, vehicle, margin)
    gap = separation(OrientedBoxes(*(t[:, None] for t in ego)), world.obstacles)  # (S, M)
    own = torch.eye(*gap.shape, dtype=torch.bool, device=gap.device)  # a slot's own car
    return float(gap.masked_fill(own, math.inf).amin())


def check_margin(margin: float, world: World, vehicle: VehicleConfig) -> None:
    """Refuse a ``BrakeConfig.margin`` that the goal itself breaks (:func:`goal_room`),
    naming the largest that it does not (to 1 mm)."""
    if margin > 0 and goal_room(world, vehicle, margin) <= 0:
        low, high = 0.0, margin
        while high - low > 1e-3:  # bisection: the room falls as the box grows
            mid = (low + high) / 2
            low, high = (mid, high) if goal_room(world, vehicle, mid) > 0 else (low, mid)
        raise ValueError(f"BrakeConfig.margin must be below {high:.3f} m in this lot (the box "
                         f"grown by more touches a parked neighbour or a wall at some goal, "
                         f"so the brake would stop every docking there), got {margin!r}")


def apply_brake(start: Tensor, pose: Tensor, v: Tensor, delta: Tensor, collision: Tensor,
                present: Tensor, angles: Tensor, world: World, cfg: ParkingConfig,
                margin: float = 0.0) -> Braking:
    """The brake on a step of dt from ``start`` (N, 3) to ``pose`` (N, 3) at the commanded
    (v, delta) (N,), where ``collision`` (N,) says the new pose touches a present obstacle
    (``present`` (N, M)). The step is blocked where it collides or, with ``margin`` m > 0,
    where the box grown by ``margin`` (:func:`fence`) was clear of every obstacle at
    ``start`` and touches one at the new pose. Where it is blocked and ``angles`` (K,) is not
    empty, the same speed at each of the K angles is tried and the unblocked one nearest
    ``delta`` taken; where none is (or K = 0) the step is not taken: the car stays at
    ``start`` at speed 0. ``start`` is collision-free (a start is, and so is every pose a
    braked step keeps), so after the brake nothing collides."""
    vehicle = cfg.vehicle
    # (N,) bool: the grown box is clear at the start (only then does the margin bind)
    fenced = ~touches_obstacle(fence(start, vehicle, margin), world, present) if margin > 0 \
        else None
    if fenced is not None:
        collision = collision | fenced & touches_obstacle(fence(pose, vehicle, margin), world,
                                                          present)
    intervened = collision
    if angles.shape[0]:
        n, k = v.shape[0], angles.shape[0]
        tries, blocked = move(start[:, None, :].expand(n, k, 3), v[:, None].expand(n, k),
                              angles.expand(n, k), present[:, None, :], world, cfg)
        if fenced is not None:
            blocked = blocked | fenced[:, None] & touches_obstacle(
                fence(tries, vehicle, margin), world, present[:, None, :])
        clear = ~blocked
        gap = (angles - delta[:, None]).abs() + torch.where(clear, 0.0, _BLOCKED)
        steered = collision & clear.any(-1)
        best = gap.argmin(-1)
        chosen = torch.take_along_dim(tries, best[:, None, None], dim=1)[:, 0]
        pose = torch.where(steered[:, None], chosen, pose)
        delta = torch.where(steered, angles[best], delta)
        collision = collision & ~steered
    pose = torch.where(collision[:, None], start, pose)
    return Braking(pose, torch.where(collision, 0.0, v), delta, collision, intervened)
