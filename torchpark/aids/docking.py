"""A docking layer under the policy: a fixed feedback law for the last metres into the slot.

The success test ``C < 4e-4`` asks for about 1 mm, 0.1 deg and 4 mm/s at once. Near the
slot axis that is a linear control problem: per metre travelled, the lateral offset e of the
rear axle changes by sin(th) and the heading error th by tan(delta) / L. The law
tan(delta) = L (-k e - 2 sqrt(k) th) makes both decay, critically damped, over about
1 / sqrt(k) m travelled, and the speed towards the goal falls with the distance left down to
a creep of mm/s. Farther off the axis the steering saturates and one pass is not enough:
the layer then drives a multi-point turn, reversing when the goal is too close (or the
emergency brake stops it) and driving in again from a run-in, each pass lining the car up
further. ``AidsConfig.docking`` (a :class:`~torchpark.aids.config.DockingConfig`) turns it
on; it engages when the car enters the funnel around the slot's approach and drives to the
episode's end. Off by default: the paper's agent is the policy alone.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.aids.config import DockingConfig
from torchpark.config import VehicleConfig
from torchpark.sim.geometry import wrap_angle


class GoalError(NamedTuple):
    """The rear axle seen from its goal pose, fields [...]: ``remaining`` m left to the goal
    along the goal's heading (> 0: the goal is ahead), ``lateral`` m left of the slot axis,
    ``heading`` rad, wrap(psi - alpha) in (-pi, pi]."""

    remaining: Tensor
    lateral: Tensor
    heading: Tensor


def error_from_goal(pose: Tensor, goal: Tensor) -> GoalError:
    """Errors of rear-axle poses [..., 3] (x m, y m, psi rad) from goal poses [..., 3]."""
    dx = goal[..., 0] - pose[..., 0]
    dy = goal[..., 1] - pose[..., 1]
    cos_a, sin_a = torch.cos(goal[..., 2]), torch.sin(goal[..., 2])
    return GoalError(cos_a * dx + sin_a * dy, sin_a * dx - cos_a * dy,
                          wrap_angle(pose[..., 2] - goal[..., 2]))


def in_funnel(error: GoalError, cfg: DockingConfig) -> Tensor:
    """Whether the docking law takes over, bool [...]: 0 <= remaining <= reach,
    |lateral| <= lateral, |heading| <= heading."""
    return ((error.remaining >= 0.0) & (error.remaining <= cfg.reach)
            & (error.lateral.abs() <= cfg.lateral) & (error.heading.abs() <= cfg.heading))


def is_settled(error: GoalError, cfg: DockingConfig) -> Tensor:
    """Whether the car is lined up for the final approach, bool [...]: within
    ``settled_lateral`` m and ``settled_heading`` rad of the slot axis."""
    return (error.lateral.abs() < cfg.settled_lateral) & (error.heading.abs() < cfg.settled_heading)


def in_settle(error: GoalError, cfg: DockingConfig) -> Tensor:
    """Where the law finishes, bool [...]: settled and within ``settle`` m of the goal,
    either side (nowhere with ``settle`` 0)."""
    return is_settled(error, cfg) & (error.remaining.abs() <= cfg.settle) & (cfg.settle > 0)


def is_fine(error: GoalError, cfg: DockingConfig) -> Tensor:
    """Whether creeping along the axis can still pass the test, bool [...]: within
    ``finish_lateral`` m and ``finish_heading`` rad of the slot axis."""
    return (error.lateral.abs() < cfg.finish_lateral) & (error.heading.abs() < cfg.finish_heading)


def in_creep(error: GoalError, reversing: Tensor, cfg: DockingConfig) -> Tensor:
    """Where the law creeps to the goal whatever its pass, bool [...]: :func:`in_settle`;
    with ``retry`` > 0 also :func:`is_fine`, unless short of the goal and driving in
    (``reversing``: bool [...]). Past the goal or backing away from it with errors the test
    cannot pass, the law then takes another pass instead (``DockingConfig.retry``)."""
    return in_settle(error, cfg) & ((cfg.retry == 0) | is_fine(error, cfg)
                                    | ((error.remaining >= 0.0) & ~reversing))


def docking_action(error: GoalError, reversing: Tensor, cfg: DockingConfig,
                   vehicle: VehicleConfig) -> tuple[Tensor, Tensor]:
    """The law's (v m/s, delta rad), each [...], within the vehicle's limits: reversing at
    ``max_speed`` where ``reversing`` (bool [...]) is set; elsewhere forwards, at
    clamp(speed_gain s, min_speed, max_speed) once settled (s m left), else at max_speed;
    :func:`in_creep`, towards the goal at clamp(speed_gain |s|, min_speed, max_speed).

    Per metre of path, forwards e' = th and th' = tan(delta) / L; reversing, e' = -th and
    th' = -tan(delta) / L. tan(delta) = L (-k e - 2 sqrt(k) d th), d = +1 forwards and -1
    reversing, gives e'' = -k e - 2 sqrt(k) e' either way: with k = gain once settled, a
    gentler forward_gain / reverse_gain (mostly saturated steering) before.
    """
    creep = in_creep(error, reversing, cfg)
    direction = torch.where(creep, torch.where(error.remaining >= 0.0, 1.0, -1.0),
                            torch.where(reversing, -1.0, 1.0))
    settled = is_settled(error, cfg)
    gain = torch.where(settled, cfg.gain,
                       torch.where(reversing, cfg.reverse_gain, cfg.forward_gain))
    tan_delta = vehicle.wheelbase * (-gain * error.lateral
                                     - 2.0 * gain.sqrt() * direction * error.heading)
    delta = torch.atan(tan_delta).clamp(-vehicle.max_steer, vehicle.max_steer)
    approach = (cfg.speed_gain * error.remaining).clamp(cfg.min_speed, cfg.max_speed)
    speed = torch.where(creep, (cfg.speed_gain * error.remaining.abs()).clamp(
        cfg.min_speed, cfg.max_speed), torch.where(settled & ~reversing, approach, cfg.max_speed))
    return direction * speed.clamp(max=vehicle.max_speed), delta


def docking_phase(error: GoalError, engaged: Tensor, reversing: Tensor, braked: Tensor,
                  cfg: DockingConfig) -> tuple[Tensor, Tensor]:
    """The layer's next (engaged, reversing), bool [...], from the current ones, the errors
    and whether the last step was stopped by the emergency brake (``braked``).

    It takes over on entering the funnel (driving forwards) and keeps the wheel. Forwards, it
    turns to reverse when braked, past the goal, or less than ``abort`` m from the goal
    without being settled; reversing, it turns forwards when braked, ``run_in`` m back, or
    settled ``retry`` m back (with ``retry`` > 0): a multi-point turn whose every pass lines
    the car up further.
    """
    entered = ~engaged & in_funnel(error, cfg)
    engaged = engaged | entered
    forwards = ~reversing | entered
    to_reverse = braked | (error.remaining < 0.0) | (
        (error.remaining < cfg.abort) & ~is_settled(error, cfg))
    to_forwards = braked | (error.remaining >= cfg.run_in) | (
        (cfg.retry > 0) & (error.remaining >= cfg.retry) & is_settled(error, cfg))
    return engaged, engaged & torch.where(forwards, to_reverse, ~to_forwards)


def take_over(pose: Tensor, goal: Tensor, v: Tensor, delta: Tensor, engaged: Tensor,
              reversing: Tensor, braked: Tensor, cfg: DockingConfig, vehicle: VehicleConfig
              ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The layer applied to one step of dt: the policy's clamped (v, delta) [...] where the
    law is not engaged, the law's where it is (it engages on entering the funnel and keeps
    the wheel to the episode's end). pose, goal: [..., 3]; engaged, reversing: the layer's
    state, bool [...]; braked: whether the emergency brake stopped the last step. Returns
    (v, delta, engaged, reversing) after this step's phase update."""
    error = error_from_goal(pose, goal)
    engaged, reversing = docking_phase(error, engaged, reversing, braked, cfg)
    law_v, law_delta = docking_action(error, reversing, cfg, vehicle)
    return (torch.where(engaged, law_v, v), torch.where(engaged, law_delta, delta), engaged,
            reversing)
