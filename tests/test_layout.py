"""The static lot (torchpark.sim.layout): slot, car, wall and goal geometry against shapely."""

from __future__ import annotations

import numpy as np
import shapely
import torch

from tests.conftest import polygon
from torchpark.sim.geometry import box_corners, boxes_overlap
from torchpark.sim.layout import SECTIONS, build_layout
from torchpark.sim.vehicle import vehicle_boxes

LEVELS = (0.0, 0.2, 0.4, 0.6, 0.8, 0.9, 1.0)


def shrunk(boxes: torch.Tensor, by: float = 1e-3) -> torch.Tensor:
    out = boxes.clone()
    out[:, 3:] -= by
    return out


def test_four_sections_of_8_to_12_slots(layout):
    counts = torch.bincount(layout.section, minlength=4).tolist()
    assert len(SECTIONS) == 4 and all(8 <= c <= 12 for c in counts)
    assert 36 <= layout.num_slots <= 44
    headings = {SECTIONS[i]: set(np.round(np.degrees(layout.slots[layout.section == i, 2].numpy())))
                for i in range(4)}
    assert headings == {"upper": {90}, "left": {-135}, "middle": {90, -90}, "right": {-45}}


def test_lot_size_is_about_40_by_30(layout):
    assert 40 <= layout.width <= 50 and 30 <= layout.height <= 37.5


def test_slots_inside_lot_and_disjoint(layout):
    corners = box_corners(layout.slots)
    assert corners[..., 0].min() >= -1e-4 and corners[..., 0].max() <= layout.width + 1e-4
    assert corners[..., 1].min() >= -1e-4 and corners[..., 1].max() <= layout.height + 1e-4
    inner = shrunk(layout.slots)
    overlap = boxes_overlap(inner[:, None], inner[None]) & ~torch.eye(layout.num_slots, dtype=bool)
    assert not overlap.any()
    polys = [polygon(b) for b in layout.slots.double().numpy()]
    for i, p in enumerate(polys):  # independent check: shapely areas, float32 slivers allowed
        assert all(p.intersection(q).area < 1e-4 for q in polys[i + 1:])


def test_every_slot_mouth_is_free_and_inside(layout):
    assert not boxes_overlap(shrunk(layout.mouths)[:, None], layout.slots[None]).any()
    corners = box_corners(layout.mouths)
    assert corners[..., 0].min() >= -1e-4 and corners[..., 0].max() <= layout.width + 1e-4
    assert corners[..., 1].min() >= -1e-4 and corners[..., 1].max() <= layout.height + 1e-4
    # the mouth is at the rear of the slot: 6 m x 2.5 m
    assert torch.allclose(layout.mouths[:, 3:], torch.tensor([3.0, 1.25]))


def test_goal_pose_centres_vehicle_nose_in(layout, config):
    box = vehicle_boxes(layout.goal_poses, config.vehicle)
    assert torch.allclose(box[:, :2], layout.slots[:, :2], atol=1e-5)
    assert torch.allclose(torch.cos(box[:, 2] - layout.slots[:, 2]), torch.ones(layout.num_slots))


def test_parked_cars_fit_in_their_slots(layout):
    for car, slot in zip(layout.cars.double().numpy(), layout.slots.double().numpy(), strict=True):
        assert polygon(slot).contains(polygon(car))


def test_walls_touch_the_lot_rectangle_from_outside(layout):
    lot = shapely.box(0, 0, layout.width, layout.height)
    for wall in layout.walls.double().numpy():
        p = polygon(wall)
        assert p.intersection(lot).area < 1e-4 and p.distance(lot) < 1e-5  # float32 slivers


def test_layout_is_identical_across_devices_and_builds(config):
    a = build_layout(config.lot, config.vehicle)
    b = build_layout(config.lot, config.vehicle)
    assert torch.equal(a.slots, b.slots) and torch.equal(a.start_pool, b.start_pool)


