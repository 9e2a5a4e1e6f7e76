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


# The float32s in [1, 8) whose cube roots lie closest to a float32 rounding midpoint (7.9 to
# 31 float64 ulps off it; found by scanning all 3 * 2**23 of them against numpy's cbrt).
HARD_BITS = (0x400353B5, 0x40526132, 0x4021B8E7, 0x3FCE4D58, 0x400F7652)


def _correctly_rounded_cbrt(x: torch.Tensor) -> torch.Tensor:
    """float32 cbrt by numpy in float64 (< 1 ulp) rounded once: correctly rounded, since no
    float32's cube root lies within 10 float64 ulps of a float32 midpoint."""
    import numpy as np

    return torch.from_numpy(np.cbrt(x.double().numpy()).astype(np.float32))


def test_the_cube_root_is_correctly_rounded_and_the_same_one_at_a_time_or_batched():
    """The reward's cube root is a function of C alone: a batch (vectorised kernels) and one
    element at a time (their scalar tails) give the same float32, the correctly rounded
    cube root, across float32's range, on the hardest cases too."""
    from torchpark.sim.reward import cube_root

    generator = torch.Generator().manual_seed(0)
    bits = torch.randint(0, 0x7F800000, (200_000,), generator=generator, dtype=torch.int64)
    hard = torch.tensor(HARD_BITS, dtype=torch.int64)
    x = torch.cat((bits, hard)).to(torch.int32).view(torch.float32)  # every finite x >= 0
    x = torch.cat((x, torch.tensor([0.0, 1e-45, 4e-4, 1.0, 8.0, 3.4e38])))
    batched = cube_root(x)
    torch.testing.assert_close(batched, _correctly_rounded_cbrt(x), rtol=0, atol=0)
    singles = torch.cat([cube_root(x[i:i + 1]) for i in range(0, x.shape[0], 997)])
    assert torch.equal(singles, batched[::997])
    assert cube_root(torch.tensor(float("nan"))).isnan()
