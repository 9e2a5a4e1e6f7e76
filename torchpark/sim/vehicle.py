"""Kinematic bicycle at the rear axle, and the vehicle's footprint box."""

from __future__ import annotations

import torch
from torch import Tensor

from torchpark.config import VehicleConfig
from torchpark.sim.geometry import OrientedBoxes, wrap_angle


def clamp_action(action: Tensor, cfg: VehicleConfig) -> tuple[Tensor, Tensor]:
    """Clamp actions [..., 2] = (v m/s, delta rad) to the vehicle limits; returns (v, delta)."""
    v = action[..., 0].clamp(-cfg.max_speed, cfg.max_speed)
    delta = action[..., 1].clamp(-cfg.max_steer, cfg.max_steer)
    return v, delta


def bicycle_step(pose: Tensor, v: Tensor, delta: Tensor, cfg: VehicleConfig) -> Tensor:
    """One explicit Euler step of the kinematic bicycle.

    pose: [..., 3] = (x m, y m, psi rad) of the rear axle centre; v: [...] m/s; delta: [...] rad.
    Returns the next pose [..., 3] with psi wrapped to (-pi, pi]:
    x += v cos(psi) dt, y += v sin(psi) dt, psi += v / L tan(delta) dt.
    """
    x, y, psi = pose.unbind(-1)
    step = v * cfg.dt
    x = x + step * torch.cos(psi)
    y = y + step * torch.sin(psi)
    psi = wrap_angle(psi + step * torch.tan(delta) / cfg.wheelbase)
    return torch.stack((x, y, psi), dim=-1)


def motion_poses(pose: Tensor, end: Tensor, v: Tensor, delta: Tensor, substeps: int,
                 cfg: VehicleConfig) -> Tensor:
    """Poses [..., substeps, 3] evenly spaced along the motion of one :func:`bicycle_step`
    from rear-axle poses ``pose`` [..., 3] at (v m/s, delta rad) [...], the last one its end
    pose ``end`` [..., 3] (the step's own result, so that its test is the end pose's).

    The Euler step read as a motion over dt: the rear axle moves straight along the start
    heading psi at speed v while the heading turns uniformly, so at the fraction s of dt the
    pose is (x + s v dt cos psi, y + s v dt sin psi, psi + s v dt tan(delta) / L); the poses
    are those at s = 1/substeps, 2/substeps, ..., 1 (headings not wrapped before the last).
    """
    fraction = torch.arange(1, substeps, device=pose.device, dtype=pose.dtype) / substeps
    x, y, psi = (t[..., None] for t in pose.unbind(-1))
    step = (v * cfg.dt)[..., None] * fraction
    inner = torch.stack((x + step * torch.cos(psi), y + step * torch.sin(psi),
                         psi + step * torch.tan(delta)[..., None] / cfg.wheelbase), dim=-1)
    return torch.cat((inner, end[..., None, :]), dim=-2)


def vehicle_obb(pose: Tensor, cfg: VehicleConfig) -> OrientedBoxes:
    """Footprint of vehicles at rear-axle poses [..., 3] as :class:`OrientedBoxes` [...]
    (:func:`footprint`)."""
    x, y, psi = pose.unbind(-1)
    # The heading's cos and sin as one stacked tensor: compiled, inductor stores the pair
    # once per pose and the per-box loops (SAT, LIDAR) load it; two separate tensors were
    # re-evaluated with libm inside every box chunk of both loops (the step's graph 2.96 ->
    # 2.27 ms at N = 16,384, bit for bit the same).
    c, s = torch.stack((torch.cos(psi), torch.sin(psi))).unbind(0)
    return footprint(x, y, c, s, cfg)


def footprint(x: Tensor, y: Tensor, cos: Tensor, sin: Tensor, cfg: VehicleConfig
              ) -> OrientedBoxes:
    """Footprint of vehicles with the rear axle at (x, y) [...] m, heading (cos, sin) [...],
    as :class:`OrientedBoxes` [...]: ``length`` x ``width``, centred ``centre_offset`` ahead
    of the rear axle."""
    half_length = torch.full_like(x, cfg.length / 2.0)
    half_width = torch.full_like(x, cfg.width / 2.0)
    offset = cfg.centre_offset
    return OrientedBoxes(x + offset * cos, y + offset * sin, cos, sin, half_length, half_width)


def vehicle_boxes(pose: Tensor, cfg: VehicleConfig) -> Tensor:
    """Footprint of vehicles at rear-axle poses [..., 3] as boxes [..., 5]."""
    f = vehicle_obb(pose, cfg)
    return torch.stack((f.cx, f.cy, pose[..., 2], f.half_length, f.half_width), dim=-1)


def gear_travel(speed: Tensor, gear: Tensor, travel: Tensor, step_time: float
                ) -> tuple[Tensor, Tensor]:
    """The car's gear and its travel since it last changed, after a step of ``step_time`` s
    at ``speed`` [...] m/s, from ``gear`` [...] (-1, 0 or 1; 0: none yet) and ``travel``
    [...] m before it: a change of gear restarts the travel, a standstill keeps the gear.
    What the planner's gear hold counts (``torchpark.experts.planner.GearHold``) and the
    policy's gear features read (``torchpark.GearTravelFeatures``)."""
    now = torch.sign(speed)
    moved = speed.abs() * step_time
    changed = (now != 0) & (now != gear)
    return torch.where(now != 0, now, gear), torch.where(changed, moved, travel + moved)
