"""What every env of a batch shares: the lot's obstacles as oriented boxes, the LIDAR's
rotations, the goal poses, and the success test's threshold; and the collision test."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.config import ParkingConfig
from torchpark.sim.geometry import OrientedBoxes, oriented_boxes, separation
from torchpark.sim.layout import LotLayout
from torchpark.sim.lidar import line_rotation

_ABSENT_GAP = 1e4  # metres


class World(NamedTuple):
    """Constants shared by every env. obstacles: OrientedBoxes (M,) = S parked-car boxes then
    4 walls; rotation: LIDAR line rotation (2, 2 * lines); goal_poses: (S, 3) rear-axle goal
    pose of each slot; slots_and_walls: OrientedBoxes (S + 4,) that a start pose must not
    touch; start_pool: (P, 3) valid start poses (the start sampler's fallback); extent: (2,)
    the lot's width and height, m; success_threshold: () the success
    test's threshold on C, a tensor so that changing it in place needs no recompilation."""

    obstacles: OrientedBoxes
    rotation: Tensor
    goal_poses: Tensor
    slots_and_walls: OrientedBoxes
    start_pool: Tensor
    extent: Tensor
    success_threshold: Tensor


def build_world(layout: LotLayout, cfg: ParkingConfig) -> World:
    """The :class:`World` of a lot layout, on the layout's device; the success threshold
    starts at ``cfg.reward.success_threshold``."""
    device = layout.slots.device
    return World(
        obstacles=OrientedBoxes(*(t.contiguous() for t in oriented_boxes(layout.obstacles))),
        rotation=line_rotation(cfg.lidar.n_rays, device),
        goal_poses=layout.goal_poses,
        slots_and_walls=layout.slots_and_walls,
        start_pool=layout.start_pool,
        extent=torch.tensor([layout.width, layout.height], device=device),
        success_threshold=torch.tensor(cfg.reward.success_threshold, dtype=torch.float32,
                                       device=device),
    )


def touches_obstacle(ego: OrientedBoxes, world: World, present: Tensor) -> Tensor:
    """Whether vehicle boxes (OrientedBoxes with fields [...]) touch a present obstacle:
    bool [...].

    present: float [..., M] broadcastable, 1 where the obstacle exists.
    """
    gap = separation(OrientedBoxes(*(t[..., None] for t in ego)), world.obstacles)
    # An absent obstacle's gap is raised by _ABSENT_GAP, far more than any overlap depth.
    return (gap + (1.0 - present) * _ABSENT_GAP).amin(-1) <= 0.0
