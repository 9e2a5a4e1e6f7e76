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


def cube_root(x: Tensor) -> Tensor:
    """The cube root of ``x`` [...] >= 0 in its dtype; for float32, correctly rounded: the same
    float32 for the same number on every path (one element or a batch, eager or compiled,
    CPU or CUDA), where ``torch.pow(x, 1/3)`` rounds by an ulp depending on whether its
    kernel is vectorised.

    Computed in float64: ``pow(x, 1/3)`` (its exponent is not exactly 1/3: relative error up
    to ~2e-15 at float32's extremes) polished by one Newton step, ``y - (y - x / y^2) / 3``,
    to about one float64 ulp (2.2e-16). No float32's cube root lies within 1.7e-15
    (relative) of a float32 rounding midpoint (all 3 * 2**23 significands of [1, 8) checked,
    and cbrt(8 x) = 2 cbrt(x)), so the float64 result rounds to the correctly rounded one.
    ``tests/test_reward.py`` holds the closest cases."""
    wide = x.double()
    y = torch.pow(wide, 1.0 / 3.0)
    y = y - (y - wide / (y * y)) / 3.0
    return torch.where(wide > 0.0, y, wide).to(x.dtype)  # 0 (and NaN) as they are


def parking_reward(cost: Tensor, collision: Tensor, success: Tensor,
                   cfg: RewardConfig) -> Tensor:
    """r = (1 - cbrt(C)) + collision_penalty [collision] + success_bonus [success], [...]
    (cbrt: :func:`cube_root`, a function of C alone)."""
    shaped = 1.0 - cube_root(cost)
    return (
        shaped
        + torch.where(collision, cfg.collision_penalty, 0.0)
        + torch.where(success, cfg.success_bonus, 0.0)
    )
