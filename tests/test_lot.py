"""Lot invariants: geometry of the layout, and the per-episode draws over seeds and levels."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
import torch

from torchpark import LotConfig, ParkingConfig, ParkingEnv
from torchpark.geometry import box_corners, boxes_overlap
from torchpark.lot import SECTIONS, build_layout
from torchpark.vehicle import vehicle_boxes

from .test_geometry import polygon

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


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("occupancy", LEVELS)
def test_draws_over_seeds_and_levels(seed, occupancy, layout, config):
    env = ParkingEnv(512, seed=seed)
    env.occupancy = occupancy
    td = env.reset()
    state = env.state
    slots = layout.num_slots
    parked = state.present[:, :slots] > 0
    expected = math.floor(occupancy * (slots - 1) + 0.5)
    assert (parked.sum(1) == expected).all()
    assert not parked.gather(1, state.goal_slot[:, None]).any()  # goal slot never occupied
    assert (state.present[:, slots:] == 1).all()  # walls always present
    assert ((state.present == 0) | (state.present == 1)).all()
    assert torch.equal(state.goal, layout.goal_poses[state.goal_slot])
    assert torch.all(td["occupancy"] == occupancy)
    # Start poses: independent shapely check against every slot and wall, no success.
    ego = vehicle_boxes(state.pose, config.vehicle).double().numpy()
    blocked = [polygon(b) for b in torch.cat((layout.slots, layout.walls)).double().numpy()]
    tree = shapely.STRtree(blocked)
    for box in ego:
        assert len(tree.query(polygon(box), predicate="intersects")) == 0
    assert not td["collision"].any() and not td["success"].any()
    x, y = state.pose[:, 0], state.pose[:, 1]
    assert ((x >= 0) & (x <= layout.width) & (y >= 0) & (y <= layout.height)).all()


def test_goals_and_parked_slots_are_spread_uniformly():
    env = ParkingEnv(20_000, seed=3)
    env.occupancy = 0.5
    env.reset()
    slots = env.layout.num_slots
    goal_counts = torch.bincount(env.state.goal_slot, minlength=slots).double()
    parked_rate = env.state.present[:, :slots].double().mean(0)
    expected = 20_000 / slots
    chi2 = ((goal_counts - expected) ** 2 / expected).sum().item()
    assert chi2 < 80  # 37 dof: p < 1e-4 above ~75
    assert (parked_rate - parked_rate.mean()).abs().max() < 0.03


def test_pool_only_start_sampler_is_valid():
    cfg = ParkingConfig(lot=LotConfig(start_candidates=0, start_pool_size=64))
    env = ParkingEnv(256, seed=0, config=cfg)
    env.reset()
    pool = env.layout.start_pool
    assert pool.shape == (64, 3)
    assert (env.state.pose[:, None] == pool[None]).all(-1).any(-1).all()
    assert not env.reset()["collision"].any()


def test_layout_is_identical_across_devices_and_builds(config):
    a = build_layout(config.lot, config.vehicle)
    b = build_layout(config.lot, config.vehicle)
    assert torch.equal(a.slots, b.slots) and torch.equal(a.start_pool, b.start_pool)


@pytest.mark.parametrize("occupancy", [0.0, 0.9])
def test_near_goal_starts_lie_near_the_goal_and_touch_nothing(occupancy, layout, config):
    lot = LotConfig(near_goal_starts=1.0)
    env = ParkingEnv(2048, seed=5, config=ParkingConfig(lot=lot))
    env.occupancy = occupancy
    td = env.reset()
    state = env.state
    # The start in the goal's slot frame: back along the slot axis, to the side, turned.
    gx, gy, alpha = state.goal.unbind(-1)
    dx, dy = state.pose[:, 0] - gx, state.pose[:, 1] - gy
    back = -(dx * torch.cos(alpha) + dy * torch.sin(alpha))
    side = -dx * torch.sin(alpha) + dy * torch.cos(alpha)
    turn = torch.remainder(state.pose[:, 2] - alpha + math.pi, 2 * math.pi) - math.pi
    near = ((back >= -1e-4) & (back <= lot.near_goal_reach + 1e-4)
            & (side.abs() <= lot.near_goal_lateral + 1e-4)
            & (turn.abs() <= lot.near_goal_heading + 1e-4))
    # Most lots have a free near-goal pose among 8 tries; the rest keep a uniform start.
    assert near.float().mean() > 0.8
    assert back[near].max() > 0.9 * lot.near_goal_reach and back[near].min() < 0.5
    # Independent check with shapely: no start touches a parked car or a wall.
    ego = vehicle_boxes(state.pose, config.vehicle).double().numpy()
    parked = (state.present[:, :layout.num_slots] > 0).numpy()
    cars = [polygon(b) for b in layout.cars.double().numpy()]
    walls = [polygon(b) for b in layout.walls.double().numpy()]
    for box, row in zip(ego, parked, strict=True):
        shape = polygon(box)
        assert not any(shape.intersects(w) for w in walls)
        assert not any(shape.intersects(c) for c, p in zip(cars, row, strict=True) if p)
    assert not td["collision"].any() and not td["success"].any()


def test_near_goal_starts_are_mixed_by_their_probability():
    half = ParkingEnv(4096, seed=4, config=ParkingConfig(lot=LotConfig(near_goal_starts=0.5)))
    half.reset()
    distance = (half.state.pose[:, :2] - half.state.goal[:, :2]).norm(dim=-1)
    # A near start is at most hypot(reach, lateral) ~ 6.1 m from the goal; uniform ones
    # mostly far more.
    share = (distance < 6.1).float().mean().item()
    assert 0.45 < share < 0.65
    uniform = ParkingEnv(4096, seed=4)
    uniform.reset()
    distance = (uniform.state.pose[:, :2] - uniform.state.goal[:, :2]).norm(dim=-1)
    assert (distance < 6.1).float().mean().item() < 0.1


@pytest.mark.parametrize("kwargs, match", [
    ({"near_goal_starts": 1.5}, r"near_goal_starts must be in \[0, 1\]"),
    ({"near_goal_reach": -1.0}, "near_goal_reach must be finite, >= 0"),
    ({"near_goal_heading": math.inf}, "near_goal_heading must be finite, >= 0"),
    ({"near_goal_candidates": 0}, r"near_goal_candidates must be an int in \[1, 1024\]"),
])
def test_bad_near_goal_options_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        LotConfig(**kwargs)
