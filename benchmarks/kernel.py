"""The floor the env's step is measured against: the paper's step (bicycle, SAT test, 16-ray
LIDAR, observation, Table-1 reward, end flags) for N lots written as the fastest torch code
found for this CPU, outside the env: no TensorDict, no action check, no aids, no reset, and
the layout the env cannot take.

- The env index is the innermost, contiguous dimension of every per-(box, env) tensor:
  (M, N), with the boxes' constants as (M, 1) columns and the presence of each box as
  (M, N); each test reduces over the boxes (dimension 0).
- The LIDAR's 4 base lines are unrolled, so one loop nest over (env, box) computes the
  slabs' faces once and keeps the 16 rays' minima in registers; inductor does so only with
  its realisation thresholds raised (:data:`OPTIONS`), which the env cannot use: its aided
  graphs then took minutes to compile (research/experiments.md, "The step at the limit").

The arithmetic of each element is the env's own (the same pure functions of
:mod:`torchpark.sim`, the same line rotation), so its outputs equal the env's step bit for
bit (``tests/test_benchmark_kernel.py``). ``python -m benchmarks.throughput --paths step
kernel`` times both in one run. Since the env's step stores the car's heading trigonometry
once per pose (``torchpark.sim.vehicle.vehicle_obb``), it is as fast as this kernel from
N = 4,096 (docs/throughput.md): the kernel is a reference point, no longer the floor.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.config import ParkingConfig
from torchpark.sim.geometry import OrientedBoxes, separation, slab_faces, slab_span
from torchpark.sim.lidar import _line_groups
from torchpark.sim.reward import is_success, parking_cost, parking_reward
from torchpark.sim.vehicle import bicycle_step, clamp_action, footprint
from torchpark.sim.world import _ABSENT_GAP, World

# inductor's options for the kernel: one loop nest for the LIDAR (see the module's text)
OPTIONS = {"realize_reads_threshold": 100, "realize_opcount_threshold": 1000}


class KernelState(NamedTuple):
    """The per-env state the kernel steps: pose (N, 3), goal (N, 3), steps (N,) int64, and
    ``present_t`` (M, N) float32, the env's ``present`` transposed (1 where box m exists in
    env n)."""

    pose: Tensor
    goal: Tensor
    steps: Tensor
    present_t: Tensor


def columns(boxes: OrientedBoxes) -> OrientedBoxes:
    """The boxes' fields (M,) as (M, 1) columns, broadcasting against (N,) per-env values."""
    return OrientedBoxes(*(t[:, None].contiguous() for t in boxes))


def lidar_env_inner(x: Tensor, y: Tensor, cos_psi: Tensor, sin_psi: Tensor, rotation: Tensor,
                    boxes: OrientedBoxes, present_t: Tensor, n_rays: int, max_range: float
                    ) -> Tensor:
    """:func:`torchpark.sim.lidar.lidar_scan` (N, n_rays) metres, bit for bit, computed over
    (box, env) with the base lines unrolled: boxes from :func:`columns`, presence (M, N)."""
    base, turned, paired = _line_groups(n_rays)
    if not (turned and paired):
        raise ValueError(f"n_rays must be a multiple of 4 here, got {n_rays}")
    directions = torch.stack((cos_psi, sin_psi), dim=-1) @ rotation  # the env's rounding
    lines = rotation.shape[1] // 2
    rx, ry = x - boxes.cx, y - boxes.cy  # (M, N)
    x_faces = slab_faces(rx * boxes.cos + ry * boxes.sin, boxes.half_length)
    y_faces = slab_faces(ry * boxes.cos - rx * boxes.sin, boxes.half_width)
    absent = (1.0 - present_t) * max_range

    def hits(x_span: tuple[Tensor, Tensor], y_span: tuple[Tensor, Tensor]
             ) -> tuple[Tensor, Tensor]:
        t_near = torch.maximum(x_span[0], y_span[0])
        t_far = torch.minimum(x_span[1], y_span[1])
        ahead = t_near.clamp(min=0.0)
        behind = t_far.clamp(max=0.0)
        return ((torch.where(t_far >= ahead, ahead, max_range) + absent).amin(0),
                (torch.where(t_near <= behind, -behind, max_range) + absent).amin(0))

    found = []  # per base line k: (base line's forward, backward), (turned line's ...)
    for k in range(base):
        line_cos, line_sin = directions[:, k], directions[:, lines + k]
        inv_x = 1.0 / (line_cos * boxes.cos + line_sin * boxes.sin)
        inv_y = 1.0 / (line_sin * boxes.cos - line_cos * boxes.sin)
        found.append((hits(slab_span(*x_faces, inv_x), slab_span(*y_faces, inv_y)),
                      hits(slab_span(*x_faces, -inv_y), slab_span(*y_faces, inv_x))))
    # Rays in the env's order: forward base, forward turned, backward base, backward turned.
    rays = [found[k][group][way] for way in (0, 1) for group in (0, 1) for k in range(base)]
    return torch.stack(rays, dim=-1).clamp(max=max_range)


def kernel_step(state: KernelState, action: Tensor, boxes: OrientedBoxes, world: World,
                cfg: ParkingConfig) -> tuple[KernelState, Tensor, Tensor, Tensor, Tensor,
                                             Tensor]:
    """The paper's step of dt for every env: the state after it, observation (N, 23),
    reward, terminated, truncated (N,) and cost C (N,), as
    :func:`torchpark.sim.step.parking_step` gives them (``boxes``: the world's obstacles as
    :func:`columns`)."""
    v, delta = clamp_action(action, cfg.vehicle)
    pose = bicycle_step(state.pose, v, delta, cfg.vehicle)
    # cos and sin as two tensors (vehicle_obb's stacked pair is inlined into every (box,
    # env) element under the kernel's raised realisation thresholds: 2-3x slower).
    psi = pose[:, 2]
    ego = footprint(pose[:, 0], pose[:, 1], torch.cos(psi), torch.sin(psi), cfg.vehicle)
    gap = separation(ego, boxes) + (1.0 - state.present_t) * _ABSENT_GAP  # (M, N)
    collision = gap.amin(0) <= 0.0
    lidar = lidar_env_inner(ego.cx, ego.cy, ego.cos, ego.sin, world.rotation, boxes,
                            state.present_t, cfg.lidar.n_rays, cfg.lidar.max_range)
    dx, dy = state.goal[:, 0] - pose[:, 0], state.goal[:, 1] - pose[:, 1]
    alpha = state.goal[:, 2]
    nav = torch.stack((dx, dy, ego.cos, ego.sin, v, torch.cos(alpha), torch.sin(alpha)), -1)
    observation = torch.cat((nav, lidar * (1.0 / cfg.lidar.max_range)), dim=-1)
    cost = parking_cost(dx, dy, pose[:, 2], alpha, v, cfg.reward)
    success = is_success(cost, world.success_threshold)
    reward = parking_reward(cost, collision, success, cfg.reward)
    terminated = collision | success
    steps = state.steps + 1
    truncated = (steps >= cfg.max_steps) & ~terminated
    return (state._replace(pose=pose, steps=steps), observation, reward, terminated,
            truncated, cost)
