"""Near-goal training starts (torchpark.aids.starts): where they lie, how often, and that
they touch nothing (shapely as the independent reference)."""

from __future__ import annotations

import math

import pytest
import torch

from tests.conftest import polygon
from torchpark import AidsConfig, NearGoalStarts, ParkingEnv
from torchpark.sim.vehicle import vehicle_boxes


@pytest.mark.parametrize("occupancy", [0.0, 0.9])
def test_near_goal_starts_lie_near_the_goal_and_touch_nothing(occupancy, layout, config):
    box = NearGoalStarts(probability=1.0)
    env = ParkingEnv(2048, seed=5, aids=AidsConfig(near_goal_starts=box))
    env.occupancy = occupancy
    td = env.reset()
    state = env.state
    # The start in the goal's slot frame: back along the slot axis, to the side, turned.
    gx, gy, alpha = state.goal.unbind(-1)
    dx, dy = state.pose[:, 0] - gx, state.pose[:, 1] - gy
    back = -(dx * torch.cos(alpha) + dy * torch.sin(alpha))
    side = -dx * torch.sin(alpha) + dy * torch.cos(alpha)
    turn = torch.remainder(state.pose[:, 2] - alpha + math.pi, 2 * math.pi) - math.pi
    near = ((back >= -1e-4) & (back <= box.reach + 1e-4)
            & (side.abs() <= box.lateral + 1e-4)
            & (turn.abs() <= box.heading + 1e-4))
    # Most lots have a free near-goal pose among 8 tries; the rest keep a uniform start.
    assert near.float().mean() > 0.8
    assert back[near].max() > 0.9 * box.reach and back[near].min() < 0.5
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
    half = ParkingEnv(4096, seed=4,
                      aids=AidsConfig(near_goal_starts=NearGoalStarts(probability=0.5)))
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
    ({"probability": 1.5}, r"NearGoalStarts.probability must be in \[0, 1\]"),
    ({"reach": -1.0}, "NearGoalStarts.reach must be finite, >= 0"),
    ({"heading": math.inf}, "NearGoalStarts.heading must be finite, >= 0"),
    ({"candidates": 0}, r"NearGoalStarts.candidates must be an int in \[1, 1024\]"),
])
def test_bad_near_goal_options_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        NearGoalStarts(**kwargs)
