"""Table 1 of the paper: the proximity cost, the reward and the success test."""

from __future__ import annotations

import torch
from torch import Tensor

from torchpark.config import RewardConfig
from torchpark.sim.geometry import wrap_angle


def parking_cost(dx: Tensor, dy: Tensor, psi: Tensor, alpha: Tensor, v: Tensor,
                 cfg: RewardConfig) -> Tensor:
    """C = w_x |dx| + w_y |dy| + w_alpha |wrap(alpha - psi)| + w_v |v|, in SI units.

    dx, dy: [...] goal minus rear axle, metres; psi, alpha: [...] vehicle and goal heading, rad;
    v: [...] speed, m/s. Returns [...] (dimensionless, >= 0).
    """
    dalpha = wrap_angle(alpha - psi)
    return cfg.w_x * dx.abs() + cfg.w_y * dy.abs() + cfg.w_alpha * dalpha.abs() + cfg.w_v * v.abs()


def is_success(cost: Tensor, threshold: Tensor | float) -> Tensor:
    """C < threshold, bool [...]. With SI units the paper's 4e-4 is about 1 mm and 0.1 deg."""
    return cost < threshold


def parking_reward(cost: Tensor, collision: Tensor, success: Tensor,
                   cfg: RewardConfig) -> Tensor:
    """r = (1 - cbrt(C)) + collision_penalty [collision] + success_bonus [success], [...]."""
    shaped = 1.0 - torch.pow(cost, 1.0 / 3.0)
    return (
        shaped
        + torch.where(collision, cfg.collision_penalty, 0.0)
        + torch.where(success, cfg.success_bonus, 0.0)
    )
