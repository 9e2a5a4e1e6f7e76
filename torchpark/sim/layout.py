"""The parking lot's static geometry, built once per env: slots, parked-car boxes, walls, goal
poses and a pool of valid start poses (the per-episode draws are in :mod:`torchpark.sim.episodes`).

Layout (world frame, x right, y up, origin at the lot's lower-left corner), four sections:

- Left: angled slots along the left wall, slot heading -135 deg, mouths opening up-right.
- Right: the mirror image along the right wall, slot heading -45 deg.
- Upper: a row perpendicular to the top wall, cars facing +90 deg, mouths onto the top lane.
- Middle: a back-to-back double row (lower half facing +90 deg, upper half -90 deg) between the
  top lane and the bottom lane.

Lanes are ``lane_width`` wide: in front of every slot's mouth a ``lane_width`` x ``slot_width``
area is free of slots and inside the lot. The lot's size follows from the slot counts (about
45 m x 35 m with the defaults). The geometry is the same for every env.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from torchpark.config import LotConfig, VehicleConfig
from torchpark.sim.geometry import OrientedBoxes, oriented_boxes, separation, wrap_angle
from torchpark.sim.vehicle import vehicle_obb

SECTIONS = ("upper", "left", "middle", "right")
UPPER, LEFT, MIDDLE, RIGHT = range(4)
LEFT_HEADING = -0.75 * math.pi
RIGHT_HEADING = -0.25 * math.pi


@dataclass(frozen=True)
class LotLayout:
    """The static geometry shared by all envs. Boxes are [..., 5] float32 (see geometry).

    slots: (S, 5) slot rectangles, half_length along the slot heading (the direction a parked
    car faces). section: (S,) int64 index into SECTIONS. mouths: (S, 5) the free lane area in
    front of each slot's mouth. cars: (S, 5) the parked-car box of each slot. walls: (4, 5)
    boxes just outside the lot rectangle [0, width] x [0, height]. goal_poses: (S, 3) rear-axle
    pose (x, y, psi) that centres the vehicle box in each slot, nose in. start_pool: (P, 3)
    valid start poses drawn once, used where every per-reset candidate is rejected.
    """

    width: float
    height: float
    slots: Tensor
    section: Tensor
    mouths: Tensor
    cars: Tensor
    walls: Tensor
    goal_poses: Tensor
    start_pool: Tensor

    @property
    def num_slots(self) -> int:
        return self.slots.shape[0]

    @property
    def obstacles(self) -> Tensor:
        """Every slot's parked car, then the four walls, (S + 4, 5)."""
        return torch.cat((self.cars, self.walls))

    @property
    def slots_and_walls(self) -> OrientedBoxes:
        """OrientedBoxes (S + 4,) of what a start pose must not touch."""
        boxes = oriented_boxes(torch.cat((self.slots, self.walls)))
        return OrientedBoxes(*(t.contiguous() for t in boxes))


def _row(centre0: tuple[float, float], step: tuple[float, float], count: int, heading: float,
         cfg: LotConfig) -> list[list[float]]:
    """``count`` slot boxes starting at ``centre0`` and advancing by ``step`` metres."""
    return [
        [centre0[0] + i * step[0], centre0[1] + i * step[1], heading,
         cfg.slot_length / 2.0, cfg.slot_width / 2.0]
        for i in range(count)
    ]


def _slot_boxes(cfg: LotConfig) -> tuple[Tensor, Tensor, float, float]:
    """Slot boxes (S, 5) float64, section ids (S,), and the lot width and height."""
    sl, sw, lane, m = cfg.slot_length, cfg.slot_width, cfg.lane_width, cfg.margin
    r2 = math.sqrt(0.5)
    ext = (sl + sw) / 2.0 * r2  # x and y half extent of a 45-degree slot
    pitch = sw / r2  # spacing along the wall that keeps 45-degree slots apart
    reach = (sl + lane) / 2.0 * r2  # slot centre to mouth-area centre, per axis
    mouth_ext = (lane + sw) / 2.0 * r2  # half extent of a 45-degree mouth area
    side = m + ext + reach + mouth_ext  # width of an angled section with its lane
    angled_rows = max(cfg.left_slots, cfg.right_slots)
    height = max(
        m + ext + (angled_rows - 1) * pitch + reach + mouth_ext + m,
        2 * m + 2 * lane + 3 * sl,
    )
    centre_width = max(cfg.upper_slots, cfg.middle_slots // 2) * sw
    width = 2 * side + centre_width

    upper_x0 = side + (centre_width - cfg.upper_slots * sw) / 2.0 + sw / 2.0
    half = cfg.middle_slots // 2
    middle_x0 = side + (centre_width - half * sw) / 2.0 + sw / 2.0
    island_bottom = height - m - sl - lane - 2 * sl
    rows = [
        (UPPER, _row((upper_x0, height - m - sl / 2.0), (sw, 0.0), cfg.upper_slots,
                     math.pi / 2.0, cfg)),
        (LEFT, _row((m + ext, m + ext), (0.0, pitch), cfg.left_slots, LEFT_HEADING, cfg)),
        (MIDDLE, _row((middle_x0, island_bottom + sl / 2.0), (sw, 0.0), half, math.pi / 2.0, cfg)
         + _row((middle_x0, island_bottom + 1.5 * sl), (sw, 0.0), half, -math.pi / 2.0, cfg)),
        (RIGHT, _row((width - m - ext, m + ext), (0.0, pitch), cfg.right_slots, RIGHT_HEADING,
                     cfg)),
    ]
    slots = torch.tensor([box for _, row in rows for box in row], dtype=torch.float64)
    section = torch.tensor([sid for sid, row in rows for _ in row], dtype=torch.int64)
    return slots, section, width, height


def _along(boxes: Tensor, distance: Tensor | float) -> Tensor:
    """Offsets [..., 2] of ``distance`` metres along each box's heading."""
    return torch.stack((torch.cos(boxes[:, 2]), torch.sin(boxes[:, 2])), dim=-1) * distance


def _walls(width: float, height: float, thickness: float) -> Tensor:
    t = thickness
    return torch.tensor(
        [
            [-t / 2, height / 2, 0.0, t / 2, height / 2 + t],
            [width + t / 2, height / 2, 0.0, t / 2, height / 2 + t],
            [width / 2, -t / 2, 0.0, width / 2 + t, t / 2],
            [width / 2, height + t / 2, 0.0, width / 2 + t, t / 2],
        ],
        dtype=torch.float64,
    )


def build_layout(lot: LotConfig, vehicle: VehicleConfig, device: torch.device | str = "cpu"
                 ) -> LotLayout:
    """Build the static lot geometry (float32 on ``device``) from its configuration."""
    slots, section, width, height = _slot_boxes(lot)
    mouths = slots.clone()
    mouths[:, :2] -= _along(slots, (lot.slot_length + lot.lane_width) / 2.0)
    mouths[:, 3] = lot.lane_width / 2.0
    cars = slots.clone()
    cars[:, 3], cars[:, 4] = lot.car_length / 2.0, lot.car_width / 2.0
    goal_xy = slots[:, :2] - _along(slots, vehicle.centre_offset)
    goal_poses = torch.cat((goal_xy, wrap_angle(slots[:, 2:3])), dim=-1)
    walls = _walls(width, height, lot.wall_thickness)
    f32: dict[str, Any] = {"dtype": torch.float32, "device": device}
    layout = LotLayout(
        width=width, height=height, slots=slots.to(**f32), section=section.to(device),
        mouths=mouths.to(**f32), cars=cars.to(**f32), walls=walls.to(**f32),
        goal_poses=goal_poses.to(**f32), start_pool=torch.empty(0, 3, **f32),
    )
    generator = torch.Generator(device=device).manual_seed(lot.pool_seed)
    pool = _rejection_sample_pool(layout, vehicle, lot.start_pool_size, generator)
    return LotLayout(**{**layout.__dict__, "start_pool": pool})


def lot_poses(unit: Tensor, extent: Tensor) -> Tensor:
    """Rear-axle poses [..., 3] from draws ``unit`` [..., 3] uniform in [0, 1): uniform over
    the lot rectangle [0, width] x [0, height] (``extent`` (2,) float32), heading uniform in
    [-pi, pi)."""
    scale = torch.cat((extent, extent.new_tensor([2.0 * math.pi])))
    return unit * scale + extent.new_tensor([0.0, 0.0, -math.pi])


def uniform_poses(layout: LotLayout, shape: tuple[int, ...], generator: torch.Generator
                  ) -> Tensor:
    """Rear-axle poses ``[*shape, 3]`` uniform over the lot rectangle, heading uniform in
    [-pi, pi)."""
    device = layout.slots.device
    extent = torch.tensor([layout.width, layout.height], device=device)
    return lot_poses(torch.rand(*shape, 3, generator=generator, device=device), extent)


def start_pose_valid(poses: Tensor, blocked: OrientedBoxes, vehicle: VehicleConfig) -> Tensor:
    """Whether rear-axle poses [..., 3] are valid starts: bool [...].

    blocked: OrientedBoxes (B,), the slots and walls. Valid means the vehicle box touches
    no wall and overlaps no slot: so it touches no parked car either, and cannot meet the
    success test, which needs the vehicle box inside the goal slot.
    """
    ego = vehicle_obb(poses, vehicle)
    return separation(OrientedBoxes(*(t[..., None] for t in ego)), blocked).amin(-1) > 0.0


_POOL_ROUNDS = 16  # a share of valid starts below 1 / 64 of the lot is refused


def _rejection_sample_pool(layout: LotLayout, vehicle: VehicleConfig, size: int,
                           generator: torch.Generator) -> Tensor:
    """``size`` valid start poses by rejection from :func:`uniform_poses` (construction only).

    At most _POOL_ROUNDS rounds of 4 x size candidates: a vehicle that fits nowhere, or in
    too small a share of the lot, is an error naming the configuration, not a hang."""
    found: list[Tensor] = []
    count = 0
    for _ in range(_POOL_ROUNDS):
        candidates = uniform_poses(layout, (4 * size,), generator)
        valid = candidates[start_pose_valid(candidates, layout.slots_and_walls, vehicle)]
        found.append(valid)
        count += valid.shape[0]
        if count >= size:
            break
    if count < size:
        raise ValueError(
            f"VehicleConfig(length={vehicle.length}, width={vehicle.width}) has room for a "
            f"start pose in {count} of {_POOL_ROUNDS * 4 * size} uniform draws over the lot: "
            f"fewer than LotConfig.start_pool_size={size} valid starts; the car does not fit "
            f"the lot's lanes (LotConfig.lane_width)")
    return torch.cat(found)[:size]
