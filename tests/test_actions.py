"""PowerActionMap: the policy's [-1, 1] actions mapped to the env's, spec and errors."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import check_env_specs

from torchpark import ParkingEnv
from torchpark.aids.actions import PowerActionMap


def make(exponents=(3.0, 1.0)) -> TransformedEnv:
    return TransformedEnv(ParkingEnv(4, seed=0), PowerActionMap([5.0, 0.785], exponents))


def test_policy_sees_unit_bounds_and_specs_hold():
    env = make()
    assert torch.equal(env.action_spec.space.low, -torch.ones(4, 2))
    assert torch.equal(env.action_spec.space.high, torch.ones(4, 2))
    check_env_specs(env)


def test_cubic_speed_and_linear_steer_reach_the_env():
    env = make()
    td = env.reset()
    u = torch.tensor([[1.0, 1.0], [0.1, -0.5], [-0.5, 0.0], [2.0, -3.0]])
    td = env.step(td.set("action", u))
    expected_v = torch.tensor([5.0, 5e-3, -0.625, 5.0])  # u clamped to [-1, 1] first
    assert torch.allclose(env.base_env.state.speed, expected_v)
    # The steer: the heading change of one step is v / L tan(delta) dt.
    assert torch.equal(td["action"], u)  # the data keeps the policy's own action


def test_map_is_odd_and_monotone():
    transform = PowerActionMap([5.0, 0.785], [3.0, 1.5])
    u = torch.linspace(-1, 1, 201)[:, None].expand(-1, 2)
    out = transform._inv_apply_transform(u)
    assert torch.allclose(out, -transform._inv_apply_transform(-u))
    assert (out.diff(dim=0) >= 0).all()
    assert torch.allclose(out[-1], torch.tensor([5.0, 0.785]))


@pytest.mark.parametrize("high, exponents, match", [
    ([5.0], [3.0, 1.0], "one length"),
    ([5.0, -1.0], [3.0, 1.0], "high must be finite and > 0"),
    ([5.0, 0.785], [0.5, 1.0], "exponents must be finite and >= 1"),
])
def test_bad_arguments_raise(high, exponents, match):
    with pytest.raises(ValueError, match=match):
        PowerActionMap(high, exponents)


def test_a_map_of_another_width_is_refused_by_the_env():
    env = TransformedEnv(ParkingEnv(2), PowerActionMap([5.0, 0.785, 1.0], [3.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="action has 2 dimensions"):
        env.rand_step(env.reset())
