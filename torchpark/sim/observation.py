"""The paper's observation: the goal offset and headings (``NAV_FIELDS``) then the LIDAR."""

from __future__ import annotations

import torch
from torch import Tensor

from torchpark.config import ParkingConfig
from torchpark.sim.lidar import lidar_scan
from torchpark.sim.reward import parking_cost
from torchpark.sim.state import ParkingState
from torchpark.sim.vehicle import vehicle_obb
from torchpark.sim.world import World

# The observation's first features, in order (dx, dy: goal minus rear axle, world frame, m;
# psi: the vehicle's heading; v: m/s; alpha: the goal's heading); the LIDAR's n_rays
# distances / max_range follow.
NAV_FIELDS = ("dx", "dy", "cos_psi", "sin_psi", "v", "cos_alpha", "sin_alpha")
NAV_DIM = len(NAV_FIELDS)
# The speed's column (m/s).
SPEED = NAV_FIELDS.index("v")


def observation_dim(cfg: ParkingConfig) -> int:
    """Length of the observation vector: NAV_DIM + n_rays (23 with the paper's 16 rays)."""
    return NAV_DIM + cfg.lidar.n_rays


def observe(state: ParkingState, world: World, cfg: ParkingConfig, scan: bool = True
            ) -> tuple[Tensor, Tensor]:
    """Observation (N, NAV_DIM + n_rays) and parking cost C (N,) of a state.

    Observation: [dx, dy, cos psi, sin psi, v, cos alpha, sin alpha, lidar / max_range], with
    dx, dy = goal - rear axle (world frame, m) and alpha the goal heading. ``scan=False``
    leaves the LIDAR's part 0 (for a step of dt whose observation nobody reads: the held
    steps of :func:`torchpark.aids.repeat.hold` but the last).
    """
    ego = vehicle_obb(state.pose, cfg.vehicle)
    if scan:
        lidar = lidar_scan(ego.cx, ego.cy, ego.cos, ego.sin, world.rotation, world.obstacles,
                           state.present, cfg.lidar.n_rays, cfg.lidar.max_range)
    else:
        lidar = state.pose.new_zeros(state.pose.shape[0], cfg.lidar.n_rays)
    dx = state.goal[:, 0] - state.pose[:, 0]
    dy = state.goal[:, 1] - state.pose[:, 1]
    alpha = state.goal[:, 2]
    nav = torch.stack(
        (dx, dy, ego.cos, ego.sin, state.speed, torch.cos(alpha), torch.sin(alpha)), dim=-1
    )
    observation = torch.cat((nav, lidar * (1.0 / cfg.lidar.max_range)), dim=-1)
    cost = parking_cost(dx, dy, state.pose[:, 2], alpha, state.speed, cfg.reward)
    return observation, cost
