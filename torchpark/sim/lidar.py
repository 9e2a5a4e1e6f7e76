"""Planar LIDAR against oriented boxes: per line a broadcast over [env, box], then a min.

The rays share work two ways. Rays k and k + n/2 are opposite, so one line's slab interval
gives both (n even). Ray k + n/4 is ray k turned by 90 degrees, so in a box's frame its line's
direction is (-dy, dx) where ray k's is (dx, dy): the two reciprocals 1/dx and 1/dy serve both
lines' slabs (n a multiple of 4). So 16 rays cost 4 base lines and 8 reciprocals per env and
box, where one reciprocal per ray and box would be 16.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from torchpark.sim.geometry import OrientedBoxes, slab_faces, slab_span


def ray_angles(n_rays: int) -> Tensor:
    """Ray angles relative to the heading, 2 pi k / n_rays for k < n_rays: (n_rays,) float64."""
    return torch.arange(n_rays, dtype=torch.float64) * (2.0 * math.pi / n_rays)


def _line_groups(n_rays: int) -> tuple[int, bool, bool]:
    """(base lines K, whether each base line is also turned by 90 degrees, whether each line
    also gives the opposite ray) for ``n_rays``: K = n/4, n/2 or n."""
    turned, paired = n_rays % 4 == 0, n_rays % 2 == 0
    return n_rays // (2 * (1 + turned)) if paired else n_rays, turned, paired


def line_rotation(n_rays: int, device: torch.device | str = "cpu") -> Tensor:
    """(2, 2 * L) float32 matrix W with [cos psi, sin psi] @ W = [cos(psi + a), sin(psi + a)]
    for the angles a of the L lines (a ray and its opposite share one when n_rays is even);
    :func:`lidar_scan` reads the base lines' columns.

    Rotating by a matrix product keeps trigonometry out of the fused ray-box kernel: inductor
    cannot inline a matmul into its consumers, so each direction is computed once per env.
    All L lines are rotated, though the turned ones are not read: the product's rounding
    depends on its width, and this width gives the directions every committed result was
    made with (the turned lines' directions are then exactly (-sin, cos) of the base lines').
    """
    angles = ray_angles(n_rays)[: n_rays // 2 if n_rays % 2 == 0 else n_rays]
    c, s = torch.cos(angles), torch.sin(angles)
    return torch.stack((torch.cat((c, s)), torch.cat((-s, c)))).to(torch.float32).to(device)


def lidar_scan(x: Tensor, y: Tensor, cos_psi: Tensor, sin_psi: Tensor, rotation: Tensor,
               obstacles: OrientedBoxes, present: Tensor, n_rays: int, max_range: float) -> Tensor:
    """Distances along n_rays rays from (x, y) at psi + 2 pi k / n_rays to the nearest present box.

    x, y: (N,) ray origin, metres; cos_psi, sin_psi: (N,) heading; rotation: from
    :func:`line_rotation`; obstacles: OrientedBoxes with fields (M,); present: (N, M) float32, 1 for
    the boxes that exist in each env, 0 for the others. Returns (N, n_rays) metres in
    [0, max_range]: 0 when the origin is inside a box, max_range when nothing is hit in range.

    A line's slab interval [t_near, t_far] gives the forward ray's hit at max(t_near, 0) when
    t_far >= that, and the backward ray's at max(-t_far, 0) when -t_near >= that.
    """
    base, turned, paired = _line_groups(n_rays)
    directions = torch.stack((cos_psi, sin_psi), dim=-1) @ rotation  # (N, 2 L)
    lines = rotation.shape[1] // 2
    # Per (env, box), (N, M): the origin in each box's frame and the slabs' faces from it.
    rx, ry = x[:, None] - obstacles.cx, y[:, None] - obstacles.cy
    x_faces = slab_faces(rx * obstacles.cos + ry * obstacles.sin, obstacles.half_length)
    y_faces = slab_faces(ry * obstacles.cos - rx * obstacles.sin, obstacles.half_width)
    # An absent box is pushed beyond range by adding max_range (arithmetic on a float mask:
    # see ParkingState.present).
    absent = (1.0 - present) * max_range

    def hits(x_span: tuple[Tensor, Tensor], y_span: tuple[Tensor, Tensor]
             ) -> tuple[Tensor, ...]:
        """The nearest hits (N,) of a line's forward (and backward) ray."""
        t_near = torch.maximum(x_span[0], y_span[0])
        t_far = torch.minimum(x_span[1], y_span[1])
        ahead = t_near.clamp(min=0.0)
        forward = (torch.where(t_far >= ahead, ahead, max_range) + absent).amin(-1)
        if not paired:
            return (forward,)
        behind = t_far.clamp(max=0.0)
        backward = (torch.where(t_near <= behind, -behind, max_range) + absent).amin(-1)
        return forward, backward

    # The base lines one by one (n_rays / 4 of them, unrolled when traced): compiled, every
    # line's reductions over the boxes share one pass, with the faces above computed once
    # per (env, box); a (N, K, M) broadcast recomputed them for each line and ran 1.33x
    # slower (inductor's defaults, N = 16,384). Bit for bit the same arithmetic.
    base_hits, turned_hits = [], []
    for k in range(base):
        # The line's direction in each box's frame, (N, M), and its two reciprocals.
        line_cos, line_sin = directions[:, k, None], directions[:, lines + k, None]
        inv_x = 1.0 / (line_cos * obstacles.cos + line_sin * obstacles.sin)
        inv_y = 1.0 / (line_sin * obstacles.cos - line_cos * obstacles.sin)
        base_hits.append(hits(slab_span(*x_faces, inv_x), slab_span(*y_faces, inv_y)))
        if turned:  # direction (-dy, dx): 1 / -dy along the box's x axis, 1 / dx along y
            turned_hits.append(hits(slab_span(*x_faces, -inv_y), slab_span(*y_faces, inv_x)))
    # Rays in order: forward base, forward turned, backward base, backward turned.
    rays = [line[i] for i in range(len(base_hits[0])) for group in (base_hits, turned_hits)
            for line in group]
    return torch.stack(rays, dim=-1).clamp(max=max_range)
