"""The per-episode runner (torchpark.runner): failure modes by their definitions, and the
aids' episode flags read from the env's declared outputs."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from torchrl.envs import TransformedEnv

from tests.conftest import act
from torchpark import (
    AidsConfig,
    BrakeConfig,
    DockingConfig,
    NearGoalStarts,
    ParkingConfig,
    ParkingEnv,
    RewardConfig,
)
from torchpark.aids.docking import error_from_goal, in_funnel
from torchpark.runner import Episodes, run_episodes
from torchpark.sim.observation import NAV_DIM


def test_failure_modes_follow_their_definitions():
    """grazing: a collision at |v| <= 1 m/s; freezing: a timeout that moved < 1 m in its last
    100 steps."""
    steps = 300
    poses = torch.zeros(steps + 1, 4, 3)
    poses[:, 2, 0] = torch.linspace(0.0, 30.0, steps + 1)  # drives on until its timeout
    poses[:200, 3, 0] = torch.linspace(0.0, 20.0, 200)  # stops after step 199, then waits
    poses[200:, 3, 0] = 20.0
    final = torch.zeros(4, NAV_DIM)
    final[:, 4] = torch.tensor([0.5, 3.0, 1.0, 0.0])  # speed at the end
    run = Episodes(success=torch.zeros(4, dtype=torch.bool),
                   collision=torch.tensor([True, True, False, False]),
                   timeout=torch.tensor([False, False, True, True]),
                   length=torch.tensor([50.0, 60.0, 300.0, 300.0]), final=final, poses=poses,
                   goal_slot=torch.zeros(4, dtype=torch.long),
                   steps=torch.tensor([50.0, 60.0, 300.0, 300.0]),
                   braked=torch.zeros(4, dtype=torch.bool),
                   docked=torch.zeros(4, dtype=torch.bool),
                   reached=torch.zeros(4, 3, dtype=torch.bool))
    assert run.grazing.tolist() == [True, False, False, False]
    assert run.freezing.tolist() == [False, False, False, True]
    # With actions held for 5 steps of dt, poses are 5 steps apart: 100 steps = 20 poses.
    held = dataclasses.replace(run, poses=poses[::5].clone(), length=run.length / 5, repeat=5)
    held.poses[41:, 3, 0] = 20.0  # stops after env step 40 (200 steps of dt), then waits
    assert held.freezing.tolist() == [False, False, False, True]


def test_braked_episodes_are_the_ones_that_collide_without_the_brake():
    """Same lots, same constant action: up to its first braked step an episode with the brake
    drives exactly as without it, so the braked ones are those that collide without it."""
    def run(brake: bool) -> Episodes:
        config = ParkingConfig(occupancy=0.9, max_steps=100)
        aids = AidsConfig(brake=BrakeConfig()) if brake else None
        env = TransformedEnv(ParkingEnv(64, seed=4, config=config, aids=aids))
        return run_episodes(lambda td: td.set("action", torch.tensor([[5.0, 0.3]]).expand(64, 2)),
                            env, 100)

    plain, braked = run(False), run(True)
    assert 0 < int(plain.collision.sum()) < 64 and not plain.braked.any()
    assert torch.equal(braked.braked, plain.collision) and not braked.collision.any()


def test_docked_counts_the_episodes_the_docking_layer_drove():
    """Near-goal starts for half the lots, a funnel as wide as their box: the episodes that
    start in it are docked, the uniform starts are not (zero actions: they stay put)."""
    near = NearGoalStarts(probability=0.5, lateral=0.1, heading=0.1)
    funnel = DockingConfig(lateral=0.1, heading=0.1)

    def run(layer: DockingConfig | None) -> tuple[Episodes, torch.Tensor]:
        base = ParkingEnv(32, seed=6, config=ParkingConfig(max_steps=50),
                          aids=AidsConfig(near_goal_starts=near, docking=layer))
        starts = []

        def policy(td):
            if not starts:  # the first call sees the start poses
                starts.append(in_funnel(error_from_goal(base.state.pose, base.state.goal),
                                        funnel))
            return td.set("action", torch.zeros(32, 2))

        return run_episodes(policy, TransformedEnv(base), 50), starts[0]

    plain, _ = run(None)
    docked, started_in_funnel = run(funnel)
    assert not plain.docked.any()
    assert torch.equal(docked.docked, started_in_funnel) and 0 < int(started_in_funnel.sum()) < 32


@pytest.mark.slow
def test_a_looser_success_test_ends_the_same_trajectory_where_the_cost_first_fell_below_it():
    """Two envs on the same lots and starts (3-5 m behind the goal, off the axis), the docking
    law driving with actions held 3 steps of dt: one with the paper's test, one with 4e-2. The
    loose env succeeds at the first env step whose ``cost`` (the lowest C over its steps of
    dt) fell below 4e-2 in the strict env, and both agree step by step until then."""
    aids = AidsConfig(action_repeat=3, docking=DockingConfig())
    strict = ParkingEnv(16, seed=2, aids=aids)
    loose = ParkingEnv(16, seed=2, aids=aids,
                       config=ParkingConfig(reward=RewardConfig(success_threshold=4e-2)))
    for env in (strict, loose):
        env.reset()
        goal = env.state.goal
        back = torch.linspace(3.0, 5.0, 16)
        side = torch.linspace(-0.5, 0.5, 16)
        c, s = torch.cos(goal[:, 2]), torch.sin(goal[:, 2])
        pose = torch.stack((goal[:, 0] - back * c - side * s, goal[:, 1] - back * s + side * c,
                            goal[:, 2] + 0.1), dim=-1)
        env.set_state(env.state._replace(pose=pose))
    zeros = torch.zeros(16, 2)
    first_below = torch.full((16,), -1)
    loose_success = torch.full((16,), -1)
    for step in range(400):
        a = act(strict, zeros)
        b = act(loose, zeros)
        first_below = torch.where((first_below < 0) & (a["cost"][:, 0] < 4e-2), step,
                                  first_below)
        loose_success = torch.where((loose_success < 0) & b["success"][:, 0], step,
                                    loose_success)
        before = loose_success < 0
        assert torch.equal(a["observation"][before], b["observation"][before])
        if bool((loose_success >= 0).all()):
            break
    assert (first_below >= 0).all()
    assert torch.equal(first_below, loose_success)


@pytest.mark.slow
def test_the_runner_reports_each_threshold_and_the_tightest_is_the_envs_success():
    near = NearGoalStarts(probability=1.0, lateral=0.5, heading=0.3)
    env = ParkingEnv(32, seed=1, config=ParkingConfig(max_steps=400),
                     aids=AidsConfig(action_repeat=2, near_goal_starts=near,
                                     docking=DockingConfig()))
    run = run_episodes(lambda td: td.set("action", torch.zeros(32, 2)), TransformedEnv(env), 400)
    assert run.thresholds == (4e-4, 4e-3, 4e-2) and run.reached.shape == (32, 3)
    assert torch.equal(run.reached[:, 0], run.success) and run.success.float().mean() > 0.5
    assert (run.reached[:, 0] <= run.reached[:, 1]).all()  # a looser test passes more often
    assert (run.reached[:, 1] <= run.reached[:, 2]).all()
