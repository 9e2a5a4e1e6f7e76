"""PowerActionMap: the policy's [-1, 1] actions mapped to the env's, spec and errors;
GearActionMap: a gear picks one of two (speed, steer) pairs."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import check_env_specs

from torchpark import ParkingEnv
from torchpark.transforms.actions import GearActionMap, PowerActionMap, gear_inverse, gear_select


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


def test_the_gear_picks_its_pair_and_a_pair_at_or_below_zero_holds():
    u = torch.tensor([[0.5, 0.8, -0.3, 0.9, 0.7],    # forwards: the first pair
                      [-0.5, 0.8, -0.3, 0.9, 0.7],   # reverse: the second, speed negated
                      [0.0, -0.4, 0.2, 0.9, 0.7],    # gear 0 is forwards; speed <= 0 holds
                      [-1.0, 0.8, -0.3, -0.2, 0.1]])  # reverse, held
    expected = torch.tensor([[0.8, -0.3], [-0.9, 0.7], [0.0, 0.2], [0.0, 0.1]])
    assert torch.equal(gear_select(u), expected)


unit = st.floats(-1.0, 1.0, allow_nan=False, width=32)


@given(speed=unit, steer=unit)
def test_the_gear_inverse_gives_the_action_the_gear_map_turns_back(speed, steer):
    u = torch.tensor([[speed, steer]])
    assert torch.equal(gear_select(gear_inverse(u)), u)


def test_the_gear_head_acts_in_five_unit_dimensions_and_reverses():
    env = TransformedEnv(ParkingEnv(4, seed=0),
                         Compose(PowerActionMap([5.0, 0.785], [3.0, 1.0]), GearActionMap()))
    assert env.action_spec.shape == (4, 5)
    assert torch.equal(env.action_spec.space.high, torch.ones(4, 5))
    check_env_specs(env)
    td = env.reset()
    u = torch.tensor([[1.0, 0.5, 0.0, 1.0, 0.0], [-1.0, 0.5, 0.0, 1.0, 0.0],
                      [-0.1, 1.0, 0.0, 0.1, 0.0], [0.3, -1.0, 0.0, 1.0, 0.0]])
    env.step(td.set("action", u))
    assert torch.allclose(env.base_env.state.speed, torch.tensor([0.625, -5.0, -5e-3, 0.0]))


def test_a_gear_map_on_an_env_in_metres_per_second_is_refused():
    env = TransformedEnv(ParkingEnv(2), GearActionMap())
    with pytest.raises(ValueError, match=r"GearActionMap needs an env acting in \[-1, 1\]\^2"):
        env.rand_step(env.reset())
