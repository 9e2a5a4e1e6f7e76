"""Near-goal training starts: a share of the resets start the car close behind its goal
(the paper's starts are uniform over the lot), so that the success bonus is seen early."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.aids.config import NearGoalStarts
from torchpark.config import ParkingConfig
from torchpark.sim.episodes import first_valid
from torchpark.sim.geometry import wrap_angle
from torchpark.sim.reward import is_success, parking_cost
from torchpark.sim.vehicle import vehicle_obb
from torchpark.sim.world import World, touches_obstacle


class NearDraw(NamedTuple):
    """Random inputs of :func:`near_start` for N envs: ``poses`` (N, J, 3) near each env's
    goal, and ``use`` (N,) bool, whether to prefer them over the uniform start."""

    poses: Tensor
    use: Tensor


def near_goal_poses(goal: Tensor, cfg: NearGoalStarts, generator: torch.Generator) -> Tensor:
    """``cfg.candidates`` rear-axle poses (N, J, 3) near each goal pose (N, 3): up to
    ``cfg.reach`` m back along the slot axis, up to ``cfg.lateral`` m to either side and up to
    ``cfg.heading`` rad off the slot heading, uniformly."""
    u = torch.rand(goal.shape[0], cfg.candidates, 3, generator=generator, device=goal.device)
    back = u[..., 0] * cfg.reach
    side = (2.0 * u[..., 1] - 1.0) * cfg.lateral
    turn = (2.0 * u[..., 2] - 1.0) * cfg.heading
    gx, gy, alpha = (t[:, None] for t in goal.unbind(-1))
    c, s = torch.cos(alpha), torch.sin(alpha)
    return torch.stack((gx - back * c - side * s, gy - back * s + side * c,
                        wrap_angle(alpha + turn)), dim=-1)


def draw_near(goal: Tensor, cfg: NearGoalStarts, generator: torch.Generator) -> NearDraw:
    """One reset's near-goal draws for goal poses (N, 3)."""
    poses = near_goal_poses(goal, cfg, generator)
    use = torch.rand(goal.shape[0], generator=generator, device=goal.device) < cfg.probability
    return NearDraw(poses, use)


def near_starts_free(near: Tensor, goal: Tensor, present: Tensor, world: World,
                     cfg: ParkingConfig) -> Tensor:
    """Whether near-goal start poses (N, J, 3) are usable, bool (N, J): rear axle inside the
    lot, vehicle box touching no present obstacle (``present`` (N, M)), success test not met
    at rest against ``goal`` (N, 3)."""
    free = ~touches_obstacle(vehicle_obb(near, cfg.vehicle), world, present[:, None, :])
    inside = ((near[..., :2] > 0.0) & (near[..., :2] < world.extent)).all(-1)
    g = goal[:, None, :]
    cost = parking_cost(g[..., 0] - near[..., 0], g[..., 1] - near[..., 1], near[..., 2],
                        g[..., 2], torch.zeros_like(near[..., 0]), cfg.reward)
    return free & inside & ~is_success(cost, world.success_threshold)


def near_start(start: Tensor, draw: NearDraw, goal: Tensor, present: Tensor, world: World,
               cfg: ParkingConfig) -> Tensor:
    """Start poses (N, 3): where ``draw.use`` is set and a near-goal pose is usable, the first
    such; else ``start`` (the paper's uniform start)."""
    chosen, found = first_valid(draw.poses, near_starts_free(draw.poses, goal, present, world,
                                                             cfg))
    return torch.where(found & draw.use[:, None], chosen, start)
