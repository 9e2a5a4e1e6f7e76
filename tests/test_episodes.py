"""Per-episode draws (torchpark.sim.episodes): goals, parked cars and start poses against
the spec, with shapely as the independent reference for the starts."""

from __future__ import annotations

import math

import pytest
import shapely
import torch

from tests.conftest import polygon
from torchpark import LotConfig, ParkingConfig, ParkingEnv
from torchpark.sim.vehicle import vehicle_boxes

LEVELS = (0.0, 0.2, 0.4, 0.6, 0.8, 0.9, 1.0)


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


@pytest.mark.slow
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


@pytest.mark.parametrize("levels", [8, None])  # keys on 8 values (many ties), or uniform
def test_parked_slots_are_the_smallest_keys_ties_by_index(levels):
    """occupied_slots against a plain reference: the `parked` non-goal slots first in
    (key, index) order, for every count from none to all."""
    from torchpark.sim.episodes import occupied_slots

    gen = torch.Generator().manual_seed(3)
    rows, slots = 400, 38
    keys = torch.rand(rows, slots, generator=gen)
    if levels is not None:
        keys = (keys * levels).floor() / levels
    goal = torch.randint(slots, (rows,), generator=gen)
    parked = torch.randint(slots, (rows,), generator=gen)  # 0 .. S - 1
    ours = occupied_slots(goal, keys, parked)
    for r in range(rows):
        order = sorted((i for i in range(slots) if i != goal[r]),
                       key=lambda i: (float(keys[r, i]), i))
        expected = torch.zeros(slots, dtype=torch.bool)
        expected[order[:int(parked[r])]] = True
        assert torch.equal(ours[r], expected), r
