"""Policy features: the goal in the vehicle's frame (geometry by hand) and the rays'
clearance (against a ray cast from outside the box, and the env's own collisions); the
transforms' specs and keys."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import check_env_specs

from tests.reference import _corners, _ray_hit
from torchpark import ClearanceFeatures, GoalFrameFeatures, ParkingConfig, ParkingEnv
from torchpark.transforms.features import box_edge_distance, goal_in_vehicle_frame


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


@pytest.mark.parametrize("n_rays, length, width", [(16, 5.0, 2.0), (7, 4.0, 1.5), (32, 3.0, 3.0)])
def test_box_edge_distance_against_a_ray_cast_from_outside(n_rays, length, width):
    """The edge along each ray from the centre, against the reference's segment-crossing ray
    cast back from 100 m out (float64)."""
    box = _corners(0.0, 0.0, 0.0, length / 2, width / 2)
    edge = box_edge_distance(n_rays, length, width)
    for k in range(n_rays):
        d = np.array([math.cos(2 * math.pi * k / n_rays), math.sin(2 * math.pi * k / n_rays)])
        expected = 100.0 - _ray_hit(100.0 * d, -d, box)
        assert edge[k].item() == pytest.approx(expected, rel=1e-6)


def test_no_ray_sees_an_obstacle_inside_the_car_unless_it_collides():
    """Where the ego box touches nothing, every ray's first hit lies outside it: each gap is
    >= 0 (up to float32 rounding of a 20 m range). Random driving in full lots comes within
    centimetres of the cars, so a wrong edge (the box's length across it) would show."""
    base = ParkingEnv(64, seed=3, config=ParkingConfig(max_steps=200))
    base.occupancy = 0.9
    env = TransformedEnv(base, ClearanceFeatures(base.config, precision=1.0))
    td = env.rollout(60, break_when_any_done=False)
    gap = torch.sinh(td["next", "observation_policy"][..., 23:])  # precision 1 m: the gap
    clear = ~td["next", "collision"][..., 0]
    assert clear.any() and (~clear).any()
    assert gap[clear].min().item() >= -1e-4
    assert gap[clear].amin(-1).min().item() < 0.3  # it came close


def test_clearance_extends_the_goal_features_in_place():
    base = ParkingEnv(4, seed=0)
    env = TransformedEnv(base, Compose(GoalFrameFeatures(),
                                       ClearanceFeatures(base.config, "observation_policy",
                                                         "observation_policy")))
    check_env_specs(env)
    td = env.reset()
    assert td["observation_policy"].shape == (4, 46)
    torch.testing.assert_close(td["observation_policy"][:, :30],
                               torch.cat([td["observation"],
                                          goal_in_vehicle_frame(td["observation"])], -1))
    edge = box_edge_distance(16, 5.0, 2.0)
    torch.testing.assert_close(td["observation_policy"][:, 30:],
                               torch.asinh((td["observation"][:, 7:] * 20.0 - edge) / 0.1))


def test_bad_clearance_arguments_are_errors():
    with pytest.raises(ValueError, match="precision must be > 0"):
        ClearanceFeatures(ParkingConfig(), precision=float("nan"))
    with pytest.raises(ValueError, match=">= 23 features"):
        ClearanceFeatures(ParkingConfig())._apply_transform(torch.zeros(3, 20))
