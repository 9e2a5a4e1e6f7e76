"""A docking layer under the policy: a fixed feedback law for the last metres into the slot.

The success test ``C < 4e-4`` asks for about 1 mm, 0.1 deg and 4 mm/s at once. Near the
slot axis that is a linear control problem: per metre travelled, the lateral offset e of the
rear axle changes by sin(th) and the heading error th by tan(delta) / L. The law
tan(delta) = L (-k e - 2 sqrt(k) th) makes both decay, critically damped, over about
1 / sqrt(k) m travelled, and the speed towards the goal falls with the distance left down to
a creep of mm/s; from an entry too close to the goal it first backs up to have that path
(``DockingConfig.run_in``). ``ParkingConfig.docking`` (a
:class:`~torchpark.config.DockingConfig`) turns it on; it engages when the car enters the
funnel behind its goal and drives to the episode's end. Off by default: the paper's agent
is the policy alone.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.config import DockingConfig, VehicleConfig


class GoalFrameError(NamedTuple):
    """The rear axle seen from its goal pose, fields [...]: ``remaining`` m left to the goal
    along the goal's heading (> 0: the goal is ahead), ``lateral`` m left of the slot axis,
    ``heading`` rad, wrap(psi - alpha) in (-pi, pi]."""

    remaining: Tensor
    lateral: Tensor
    heading: Tensor


def goal_frame_error(pose: Tensor, goal: Tensor) -> GoalFrameError:
    """Errors of rear-axle poses [..., 3] (x m, y m, psi rad) from goal poses [..., 3]."""
    dx = goal[..., 0] - pose[..., 0]
    dy = goal[..., 1] - pose[..., 1]
    cos_a, sin_a = torch.cos(goal[..., 2]), torch.sin(goal[..., 2])
    turn = pose[..., 2] - goal[..., 2]
    return GoalFrameError(cos_a * dx + sin_a * dy, sin_a * dx - cos_a * dy,
                          torch.atan2(torch.sin(turn), torch.cos(turn)))


def in_funnel(error: GoalFrameError, cfg: DockingConfig) -> Tensor:
    """Whether the docking law takes over, bool [...]: 0 <= remaining <= reach,
    |lateral| <= lateral, |heading| <= heading."""
    return ((error.remaining >= 0.0) & (error.remaining <= cfg.reach)
            & (error.lateral.abs() <= cfg.lateral) & (error.heading.abs() <= cfg.heading))


def docking_action(error: GoalFrameError, backing: Tensor, cfg: DockingConfig,
                   vehicle: VehicleConfig) -> tuple[Tensor, Tensor]:
    """The law's (v m/s, delta rad), each [...], within the vehicle's limits: where
    ``backing`` (bool [...]) is set, reversing at ``max_speed``; elsewhere towards the goal,
    reversing once past it.

    Per metre of path, forwards e' = th and th' = tan(delta) / L; reversing, e' = -th and
    th' = -tan(delta) / L. tan(delta) = L (-k e - 2 sqrt(k) d th), d = +1 forwards and -1
    reversing, gives e'' = -k e - 2 sqrt(k) e' either way.
    """
    direction = torch.where(backing | (error.remaining < 0.0), -1.0, 1.0)
    tan_delta = vehicle.wheelbase * (-cfg.gain * error.lateral
                                     - 2.0 * cfg.gain ** 0.5 * direction * error.heading)
    delta = torch.atan(tan_delta).clamp(-vehicle.max_steer, vehicle.max_steer)
    speed = (cfg.speed_gain * error.remaining.abs()).clamp(cfg.min_speed, cfg.max_speed)
    speed = torch.where(backing, cfg.max_speed, speed)
    return direction * speed.clamp(max=vehicle.max_speed), delta


def docking_phase(error: GoalFrameError, docking: Tensor, backing: Tensor, cfg: DockingConfig
                  ) -> tuple[Tensor, Tensor]:
    """The layer's next (docking, backing), bool [...], from the current ones and the errors:
    it takes over on entering the funnel and keeps the wheel; it backs up from an entry less
    than ``run_in`` m behind the goal until the goal is that far ahead, and never again."""
    entered = ~docking & in_funnel(error, cfg)
    short = error.remaining < cfg.run_in
    return docking | entered, torch.where(entered, short, backing & short)
