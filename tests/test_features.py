"""Goal-in-vehicle-frame features: geometry by hand, the transform's spec and keys."""

from __future__ import annotations

import math

import pytest
import torch
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import check_env_specs

from torchpark import GoalFrameFeatures, ParkingEnv
from torchpark.aids.features import goal_in_vehicle_frame


def observation(dx, dy, psi, alpha) -> torch.Tensor:
    nav = [dx, dy, math.cos(psi), math.sin(psi), 0.0, math.cos(alpha), math.sin(alpha)]
    return torch.tensor([nav + [1.0] * 16])


@pytest.mark.parametrize("dx, dy, psi, alpha, ex, ey, err", [
    (3.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0),  # goal straight ahead
    (0.0, 3.0, math.pi / 2, math.pi / 2, 3.0, 0.0, 0.0),  # facing +y, goal ahead
    (0.0, 3.0, 0.0, math.pi / 2, 0.0, 3.0, math.pi / 2),  # goal on the left, turned left
    (-2.0, 0.0, math.pi / 2, -math.pi / 2 + 0.1, 0.0, 2.0, -math.pi + 0.1),  # left, reversed
    (1.0, 1.0, -3 * math.pi / 4, math.pi, -math.sqrt(2), 0.0, -math.pi / 4),
])
def test_goal_seen_from_the_car(dx, dy, psi, alpha, ex, ey, err):
    f = goal_in_vehicle_frame(observation(dx, dy, psi, alpha), precision=0.01)[0]
    assert f[0].item() == pytest.approx(ex, abs=1e-5)
    assert f[1].item() == pytest.approx(ey, abs=1e-5)
    assert (f[2].item(), f[3].item()) == pytest.approx((math.cos(err), math.sin(err)), abs=1e-6)
    assert f[4].item() == pytest.approx(math.asinh(ex / 0.01), abs=1e-3)
    assert f[6].item() == pytest.approx(math.asinh(math.atan2(math.sin(err), math.cos(err))
                                                   / 0.01), abs=1e-3)


def test_transform_appends_features_and_keeps_the_observation():
    env = TransformedEnv(ParkingEnv(4, seed=0), GoalFrameFeatures())
    check_env_specs(env)
    td = env.reset()
    assert td["observation_policy"].shape == (4, 30)
    torch.testing.assert_close(td["observation_policy"][:, :23], td["observation"])
    torch.testing.assert_close(td["observation_policy"][:, 23:],
                               goal_in_vehicle_frame(td["observation"]))


def test_bad_arguments_are_errors():
    with pytest.raises(ValueError, match="precision must be > 0"):
        GoalFrameFeatures(precision=0.0)
    with pytest.raises(ValueError, match=">= 7 features"):
        goal_in_vehicle_frame(torch.zeros(3, 5))
