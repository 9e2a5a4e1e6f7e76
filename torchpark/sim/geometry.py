"""Oriented boxes in the plane: corners, SAT overlap and ray casting.

A box is a tensor ``[..., 5]`` = (cx, cy, heading, half_length, half_width): centre in metres,
heading in radians counter-clockwise from +x (the direction of the half_length axis), half
extents in metres. Every function broadcasts over the leading dimensions, works for any float
dtype and device, has no data-dependent control flow and compiles with
``torch.compile(fullgraph=True)``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

# A line origin exactly on a slab face is moved this far inside the slab (metres), so that a
# line along the face, whose parameter there would be 0 * inf = NaN, stays in the closed slab.
_ON_FACE = 1e-30


def wrap_angle(angle: Tensor) -> Tensor:
    """Wrap radians to (-pi, pi]. Shape and dtype are kept; angles already in range are
    returned unchanged (shifting by pi and back would round them, and the reward's cube root
    turns a 1e-7 rad rounding into a 4e-3 reward error at the goal)."""
    wrapped = torch.remainder(angle + math.pi, 2.0 * math.pi) - math.pi
    # remainder gives [-pi, pi); move -pi to +pi so the interval is (-pi, pi].
    wrapped = torch.where(wrapped <= -math.pi, wrapped + 2.0 * math.pi, wrapped)
    return torch.where((angle > -math.pi) & (angle <= math.pi), angle, wrapped)


class OrientedBoxes(NamedTuple):
    """A box as separate component tensors, so constant boxes are prepared once.

    Every field is [...]: centre (cx, cy) in metres; cos and sin of the heading; half_length
    along the heading axis u = (cos, sin) and half_width along n = (-sin, cos), in metres.
    Separate fields (not stacked [..., 2] pairs) keep compiled kernels fused: summing size-2
    dims made the compiled LIDAR 2.5x slower.
    """

    cx: Tensor
    cy: Tensor
    cos: Tensor
    sin: Tensor
    half_length: Tensor
    half_width: Tensor


def oriented_boxes(boxes: Tensor) -> OrientedBoxes:
    """Split boxes [..., 5] into a :class:`OrientedBoxes` (one cos and sin per box)."""
    heading = boxes[..., 2]
    return OrientedBoxes(
        boxes[..., 0], boxes[..., 1], torch.cos(heading), torch.sin(heading),
        boxes[..., 3], boxes[..., 4],
    )


def box_corners(boxes: Tensor) -> Tensor:
    """Corners of boxes, counter-clockwise from front-right.

    boxes: [..., 5]. Returns [..., 4, 2] in metres, in the order front-right, front-left,
    rear-left, rear-right, where front is +u and left is +n.
    """
    f = oriented_boxes(boxes)
    centre = boxes[..., :2]
    hu = torch.stack((f.cos, f.sin), dim=-1) * f.half_length[..., None]
    hn = torch.stack((-f.sin, f.cos), dim=-1) * f.half_width[..., None]
    corners = (centre + hu - hn, centre + hu + hn, centre - hu + hn, centre - hu - hn)
    return torch.stack(corners, dim=-2)


def boxes_overlap(a: Tensor, b: Tensor) -> Tensor:
    """Separating axis test between oriented boxes; touching counts as overlap.

    a, b: [..., 5], broadcast against each other. Returns bool [...]: True when the closed boxes
    share at least one point.
    """
    return separation(oriented_boxes(a), oriented_boxes(b)) <= 0.0


def separation(a: OrientedBoxes, b: OrientedBoxes) -> Tensor:
    """Largest separating-axis gap between boxes, metres [...]; <= 0 means they overlap or touch.

    The candidate axes are the two face normals of each box. On each, the gap is the distance
    between the centres' projections minus the two projected half extents; the boxes are apart
    iff some gap is > 0 (touching: the largest gap is exactly 0). Float max, not boolean logic:
    it compiles to branch-free vector code.
    """
    dx, dy = b.cx - a.cx, b.cy - a.cy
    # |cosines| between the axes of a (u_a, n_a) and of b (u_b, n_b), shared by all projections.
    cos_ab = a.cos * b.cos + a.sin * b.sin  # u_a . u_b  =  n_a . n_b
    sin_ab = a.cos * b.sin - a.sin * b.cos  # n_a . u_b  = -u_a . n_b
    c, s = cos_ab.abs(), sin_ab.abs()
    la, wa, lb, wb = a.half_length, a.half_width, b.half_length, b.half_width
    gap_ua = (dx * a.cos + dy * a.sin).abs() - (la + lb * c + wb * s)
    gap_na = (dy * a.cos - dx * a.sin).abs() - (wa + lb * s + wb * c)
    gap_ub = (dx * b.cos + dy * b.sin).abs() - (la * c + wa * s + lb)
    gap_nb = (dy * b.cos - dx * b.sin).abs() - (la * s + wa * c + wb)
    return torch.maximum(torch.maximum(gap_ua, gap_na), torch.maximum(gap_ub, gap_nb))


def ray_box_distance(origins: Tensor, angles: Tensor, boxes: Tensor, max_range: float) -> Tensor:
    """Distance along rays to the boundary of oriented boxes (slab test in the box frame).

    origins: [..., 2] metres; angles: [...] radians (world frame); boxes: [..., 5]; all three
    broadcast together (origins and boxes without their last dimension). Returns [...] metres:
    the distance to the first boundary point along the ray, 0 when the origin is inside or on the
    box, and ``max_range`` when the ray misses or the hit lies farther than ``max_range``. Never
    NaN or inf, also for rays parallel to an edge.
    """
    t_near, t_far = slab_interval(origins[..., 0], origins[..., 1], torch.cos(angles),
                                  torch.sin(angles), oriented_boxes(boxes))
    hit = (t_far >= t_near) & (t_far >= 0.0)
    return torch.where(hit, t_near.clamp(min=0.0), max_range).clamp(max=max_range)


def slab_faces(offset: Tensor, half: Tensor) -> tuple[Tensor, Tensor]:
    """The faces of the slab [-half, half] relative to a line origin at ``offset`` on the
    slab's axis, metres [...]: (lower, upper) = (-half - offset, half - offset).

    A face exactly at the origin (0) is moved ``_ON_FACE`` outwards, so the origin is strictly
    inside the closed slab and :func:`slab_span` needs no branch for a line along the face.
    """
    lower, upper = -half - offset, half - offset
    return (torch.where(lower == 0.0, -_ON_FACE, lower),
            torch.where(upper == 0.0, _ON_FACE, upper))


def slab_span(lower: Tensor, upper: Tensor, inverse: Tensor) -> tuple[Tensor, Tensor]:
    """Parameter interval [lo, hi] where ``origin + t direction`` is in a slab, from its faces
    (:func:`slab_faces`) and the reciprocal ``inverse`` = 1 / (direction along the axis).

    Branch-free for lines parallel to the slab: their reciprocal is +-inf (IEEE 1 / +-0), so
    the interval is (-inf, inf) when the origin is inside the slab and empty ([inf, inf] or
    [-inf, -inf], which no other slab's interval meets) when it is outside; the faces are never
    0 (:func:`slab_faces`), so 0 * inf = NaN cannot occur.
    """
    t1, t2 = lower * inverse, upper * inverse
    return torch.minimum(t1, t2), torch.maximum(t1, t2)


def slab_interval(x: Tensor, y: Tensor, cos: Tensor, sin: Tensor, boxes: OrientedBoxes
                  ) -> tuple[Tensor, Tensor]:
    """Parameter interval [t_near, t_far] where the line (x, y) + t (cos, sin) is in the box.

    All arguments broadcast; (cos, sin) must be a unit vector, so t is in metres. The line
    meets the closed box iff t_near <= t_far (both +-inf for a line parallel to an edge that
    misses the box, and never NaN).
    """
    rx, ry = x - boxes.cx, y - boxes.cy
    # Line origin and direction in the box frame (x along u, y along n).
    ox, oy = rx * boxes.cos + ry * boxes.sin, ry * boxes.cos - rx * boxes.sin
    dx, dy = cos * boxes.cos + sin * boxes.sin, sin * boxes.cos - cos * boxes.sin
    x_lo, x_hi = slab_span(*slab_faces(ox, boxes.half_length), 1.0 / dx)
    y_lo, y_hi = slab_span(*slab_faces(oy, boxes.half_width), 1.0 / dy)
    return torch.maximum(x_lo, y_lo), torch.minimum(x_hi, y_hi)
