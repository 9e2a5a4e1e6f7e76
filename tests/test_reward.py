"""Table 1 (torchpark.sim.reward): the cost, the success test and the reward, against the
paper's formulas written out in float64."""

from __future__ import annotations

import math

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from torchpark import RewardConfig
from torchpark.sim.reward import is_success, parking_cost, parking_reward

finite = st.floats(-50.0, 50.0, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(dx=finite, dy=finite, psi=finite, alpha=finite, v=st.floats(-5.0, 5.0))
def test_cost_is_the_papers_weighted_sum(dx, dy, psi, alpha, v):
    cfg = RewardConfig()
    tensors = (torch.tensor(x, dtype=torch.float64) for x in (dx, dy, psi, alpha, v))
    cost = parking_cost(*tensors, cfg).item()
    dalpha = math.remainder(alpha - psi, 2 * math.pi)
    expected = 0.35 * abs(dx) + 0.35 * abs(dy) + 0.2 * abs(dalpha) + 0.1 * abs(v)
    assert math.isclose(cost, expected, rel_tol=1e-9, abs_tol=1e-9)


def test_reward_adds_the_collision_penalty_and_the_success_bonus():
    cfg = RewardConfig()
    cost = torch.tensor([0.0, 0.125, 1.0, 8.0, 1e-4], dtype=torch.float64)
    collision = torch.tensor([False, True, False, True, False])
    success = is_success(cost, cfg.success_threshold)
    assert success.tolist() == [True, False, False, False, True]
    reward = parking_reward(cost, collision, success, cfg)
    expected = [1 + 1000, 0.5 - 200, 0.0, -1.0 - 200, 1 - 1e-4 ** (1 / 3) + 1000]
    assert torch.allclose(reward, torch.tensor(expected, dtype=torch.float64))


def test_the_success_test_is_strict_and_takes_a_tensor_threshold():
    threshold = torch.tensor(4e-4)
    cost = torch.tensor([3.99e-4, 4e-4, 4.01e-4])
    assert is_success(cost, threshold).tolist() == [True, False, False]
