"""The paper's step (torchpark.sim.step) through ParkingEnv: collision, success, reward and
truncation in hand-placed situations."""

from __future__ import annotations

import math

import pytest
import torch

from tests.conftest import act, place
from torchpark import ParkingConfig, ParkingEnv


def test_reward_recomputed_from_observation(device):
    env = ParkingEnv(32, seed=2, device=device)
    env.occupancy = 0.6
    rollout = env.rollout(60, policy=None, break_when_any_done=False).cpu()
    nxt = rollout["next"]
    obs, reward = nxt["observation"], nxt["reward"][..., 0]
    live = ~nxt["terminated"][..., 0]
    assert live.sum() > 1000
    psi = torch.atan2(obs[..., 3], obs[..., 2])
    alpha = torch.atan2(obs[..., 6], obs[..., 5])
    dalpha = torch.remainder(alpha - psi + math.pi, 2 * math.pi) - math.pi
    cost = (0.35 * obs[..., 0].abs() + 0.35 * obs[..., 1].abs() + 0.2 * dalpha.abs()
            + 0.1 * obs[..., 4].abs())
    expected = 1 - cost ** (1 / 3)
    assert torch.allclose(reward[live], expected[live], atol=1e-5)
    collided = nxt["collision"][..., 0]
    assert collided.any()
    assert torch.allclose(reward[collided], expected[collided] - 200, atol=1e-4)


def test_driving_into_a_wall_collides_and_terminates():
    env = ParkingEnv(1, seed=0)
    env.reset()
    width = env.layout.width
    # Facing +x, front bumper 0.3 m from the right wall; on the bottom lane, away from slots.
    place(env, torch.tensor([width - 4.5 - 0.3, 3.0, 0.0]))
    first = act(env, [2.0, 0.0])  # 0.2 m: still clear
    assert not first["collision"].item() and not first["done"].item()
    second = act(env, [2.0, 0.0])  # 0.4 m: through the wall line
    assert second["collision"].item() and second["terminated"].item() and second["done"].item()
    assert not second["truncated"].item()
    obs = second["observation"][0].tolist()
    cost = 0.35 * abs(obs[0]) + 0.35 * abs(obs[1]) + 0.1 * 2.0 + 0.2 * abs(
        math.remainder(math.atan2(obs[6], obs[5]) - math.atan2(obs[3], obs[2]), 2 * math.pi))
    assert second["reward"].item() == pytest.approx(1 - cost ** (1 / 3) - 200, abs=1e-4)


def test_standing_in_an_empty_slot_is_no_collision_but_a_parked_car_is():
    env = ParkingEnv(2, seed=0)
    env.occupancy = 0.5
    env.reset()
    present = env.state.present[:, : env.layout.num_slots]
    empty = int(torch.nonzero((present[0] == 0) & (torch.arange(present.shape[1]) !=
                                                   env.state.goal_slot[0]))[0])
    full = int(torch.nonzero(present[1] == 1)[0])
    place(env, env.layout.goal_poses[[empty, full]])
    out = act(env, [0.0, 0.0])
    assert out["collision"][:, 0].tolist() == [False, True]


def test_touching_the_wall_counts():
    env = ParkingEnv(1, seed=0)
    env.reset()
    place(env, torch.tensor([env.layout.width - 4.5 - 0.25, 3.0, 0.0]))
    assert act(env, [2.5, 0.0])["collision"].item()  # front exactly on the wall's face


def test_placing_the_car_on_its_goal_succeeds():
    env = ParkingEnv(8, seed=3)
    env.occupancy = 0.9
    env.reset()
    place(env, env.state.goal)
    out = act(env, [0.0, 0.0])
    assert out["success"].all() and out["terminated"].all() and not out["collision"].any()
    assert torch.allclose(out["reward"], torch.full((8, 1), 1001.0))


def test_driving_onto_the_goal_succeeds_within_threshold():
    env = ParkingEnv(4, seed=4)
    env.reset()
    goal = env.state.goal
    back = torch.stack((torch.cos(goal[:, 2]), torch.sin(goal[:, 2])), -1) * 1e-4
    place(env, torch.cat((goal[:, :2] - back, goal[:, 2:]), -1))
    out = act(env, [1e-3, 0.0])  # 0.1 mm forward at 1 mm/s: C ~ 1e-4 < 4e-4
    assert out["success"].all()
    assert (out["reward"] > 1000.9).all()


def test_truncation_at_step_limit():
    env = ParkingEnv(3, seed=5, config=ParkingConfig(max_steps=7))
    env.reset()
    for step in range(1, 8):
        out = act(env, [0.0, 0.0])  # standing still: no collision, no success
        assert out["truncated"].all() == (step == 7)
        assert out["done"].all() == (step == 7) and not out["terminated"].any()


def test_out_of_range_actions_are_clamped():
    a, b = ParkingEnv(2, seed=6), ParkingEnv(2, seed=6)
    a.reset(), b.reset()
    out_a = act(a, [[50.0, 3.0], [-50.0, -3.0]])
    out_b = act(b, [[5.0, 0.785], [-5.0, -0.785]])
    assert torch.equal(out_a["observation"], out_b["observation"])
