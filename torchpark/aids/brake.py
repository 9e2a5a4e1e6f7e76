"""An emergency brake under the policy: a step of dt that would end in a collision is not
taken (or, with ``steer_clear``, is steered clear of it), so no collision can happen."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.aids.config import BrakeConfig
from torchpark.config import ParkingConfig
from torchpark.sim.step import move
from torchpark.sim.world import World

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


def apply_brake(start: Tensor, pose: Tensor, v: Tensor, delta: Tensor, collision: Tensor,
                present: Tensor, angles: Tensor, world: World, cfg: ParkingConfig) -> Braking:
    """The brake on a step of dt from ``start`` (N, 3) to ``pose`` (N, 3) at the commanded
    (v, delta) (N,), where ``collision`` (N,) says the new pose touches a present obstacle
    (``present`` (N, M)). Where it does and ``angles`` (K,) is not empty, the same speed at
    each of the K angles is tried and the clear one nearest ``delta`` taken; where none is
    clear (or K = 0) the step is not taken: the car stays at ``start`` at speed 0. ``start``
    is collision-free (a start is, and so is every pose a braked step keeps), so after the
    brake nothing collides."""
    intervened = collision
    if angles.shape[0]:
        n, k = v.shape[0], angles.shape[0]
        tries, blocked = move(start[:, None, :].expand(n, k, 3), v[:, None].expand(n, k),
                              angles.expand(n, k), present[:, None, :], world, cfg)
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
