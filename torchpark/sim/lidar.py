"""Planar LIDAR against oriented boxes: one broadcast over [env, line, box], then a min."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from torchpark.sim.geometry import OrientedBoxes, slab_interval


def ray_angles(n_rays: int) -> Tensor:
    """Ray angles relative to the heading, 2 pi k / n_rays for k < n_rays: (n_rays,) float64."""
    return torch.arange(n_rays, dtype=torch.float64) * (2.0 * math.pi / n_rays)


def line_rotation(n_rays: int, device: torch.device | str = "cpu") -> Tensor:
    """(2, 2 * n_lines) float32 matrix W with [cos psi, sin psi] @ W = [cos(psi + a), sin(psi + a)]
    for the line angles a; a ray pair k, k + n_rays / 2 shares a line when n_rays is even.

    Rotating by a matrix product keeps trigonometry out of the fused ray-box kernel: inductor
    cannot inline a matmul into its consumers, so each direction is computed once per env.
    """
    angles = ray_angles(n_rays)[: _num_lines(n_rays)]
    c, s = torch.cos(angles), torch.sin(angles)
    return torch.stack((torch.cat((c, s)), torch.cat((-s, c)))).to(torch.float32).to(device)


def _num_lines(n_rays: int) -> int:
    return n_rays // 2 if n_rays % 2 == 0 else n_rays


def lidar_scan(x: Tensor, y: Tensor, cos_psi: Tensor, sin_psi: Tensor, rotation: Tensor,
               obstacles: OrientedBoxes, present: Tensor, n_rays: int, max_range: float) -> Tensor:
    """Distances along n_rays rays from (x, y) at psi + 2 pi k / n_rays to the nearest present box.

    x, y: (N,) ray origin, metres; cos_psi, sin_psi: (N,) heading; rotation: from
    :func:`line_rotation`; obstacles: OrientedBoxes with fields (M,); present: (N, M) float32, 1 for
    the boxes that exist in each env, 0 for the others. Returns (N, n_rays) metres in
    [0, max_range]: 0 when the origin is inside a box, max_range when nothing is hit in range.

    With an even ray count, rays k and k + n_rays / 2 are opposite, so one slab interval
    [t_near, t_far] per line gives both: the forward ray hits at max(t_near, 0) when
    t_far >= 0, the backward one at max(-t_far, 0) when t_near <= 0. That halves the work.
    """
    lines = _num_lines(n_rays)
    directions = torch.stack((cos_psi, sin_psi), dim=-1) @ rotation  # (N, 2 * lines)
    t_near, t_far = slab_interval(
        x[:, None, None], y[:, None, None],
        directions[:, :lines, None], directions[:, lines:, None], obstacles,
    )  # (N, lines, M)
    # Absent boxes are pushed beyond range by adding max_range (arithmetic on a float mask:
    # see ParkingState.present).
    absent = ((1.0 - present) * max_range)[:, None, :]
    hit = t_far >= t_near
    forward = torch.where(hit & (t_far >= 0.0), t_near.clamp(min=0.0), max_range)
    forward = (forward + absent).amin(-1)
    if lines == n_rays:
        return forward.clamp(max=max_range)
    backward = torch.where(hit & (t_near <= 0.0), (-t_far).clamp(min=0.0), max_range)
    backward = (backward + absent).amin(-1)
    return torch.cat((forward, backward), dim=-1).clamp(max=max_range)
