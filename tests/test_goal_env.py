"""torchpark/ParkingGoal-v0: Gymnasium-Robotics' GoalEnv interface for hindsight relabelling
(Stable-Baselines3's HerReplayBuffer)."""

import gymnasium
import numpy as np
import pytest
import torch

import torchpark  # noqa: F401  (registers the ids)
from torchpark.goal_env import GOAL_ENV_ID, goal_observation
from torchpark.gym_env import ENV_ID


def test_goal_env_passes_gymnasium_and_sb3_checks():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gymnasium.make(GOAL_ENV_ID, seed=0)
    assert set(env.observation_space.spaces) == {"observation", "achieved_goal", "desired_goal"}
    assert env.observation_space["observation"].shape == (21,)
    assert env.observation_space["desired_goal"].shape == (4,)
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped)  # SB3 checks compute_reward against the step's reward too


def test_goal_observation_is_the_papers_split_by_goal():
    env = gymnasium.make(GOAL_ENV_ID, seed=3, occupancy=0.5).unwrapped
    paper = gymnasium.make(ENV_ID, seed=3, occupancy=0.5).unwrapped
    obs, _ = env.reset(seed=5)
    flat, _ = paper.reset(seed=5)
    goal, achieved = obs["desired_goal"], obs["achieved_goal"]
    np.testing.assert_allclose(goal[:2] - achieved[:2], flat[:2], atol=1e-5)  # dx, dy
    np.testing.assert_array_equal(obs["observation"][2:], flat[2:5].tolist() + flat[7:].tolist())
    np.testing.assert_allclose([np.cos(goal[2]), np.sin(goal[2])], flat[5:7], atol=1e-6)
    assert goal[3] == 0 and achieved[3] == 0  # at rest at the start, and asked to stop


def _transitions(occupancy: float, steps: int, seed: int):
    """(achieved, desired, info, reward) of every step of random driving, episodes restarted."""
    env = gymnasium.make(GOAL_ENV_ID, seed=seed, occupancy=occupancy)
    env.action_space.seed(seed)
    obs, _ = env.reset(seed=seed)
    rows = []
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        rows.append((obs["achieved_goal"], obs["desired_goal"], info, reward))
        if terminated or truncated:
            obs, _ = env.reset()
    return env, rows


def _success_transition(env):
    """A step that ends at the goal: the car put at rest on the goal, then held still."""
    base = env.unwrapped.env
    env.reset(seed=11)
    state = base.state
    base.set_state(state._replace(pose=state.goal.clone(), speed=torch.zeros_like(state.speed)))
    obs, reward, terminated, _, info = env.step(np.zeros(2, np.float32))
    assert terminated and info["success"] and info["is_success"]
    return obs["achieved_goal"], obs["desired_goal"], info, reward


@pytest.mark.slow
def test_compute_reward_is_the_envs_reward_on_real_transitions():
    env, rows = _transitions(occupancy=0.9, steps=600, seed=2)
    rows.append(_success_transition(env))
    achieved, desired = np.stack([r[0] for r in rows]), np.stack([r[1] for r in rows])
    infos = [r[2] for r in rows]
    rewards = np.array([r[3] for r in rows], np.float32)
    assert any(i["collision"] for i in infos) and any(i["success"] for i in infos)
    goal_env = env.unwrapped
    batched = goal_env.compute_reward(achieved, desired, infos)  # as HER calls it
    assert batched.shape == (len(rows),) and batched.dtype == np.float32
    # The same float32 functions on the same numbers (the cube root correctly rounded, the
    # same one batched or not): equal to the last bit.
    np.testing.assert_array_equal(batched, rewards)
    one = [goal_env.compute_reward(a, d, i) for a, d, i, _ in rows]  # one goal at a time
    np.testing.assert_array_equal(np.array(one, np.float32), rewards)
    ended = goal_env.compute_terminated(achieved, desired, infos)
    np.testing.assert_array_equal(ended, [i["collision"] or i["success"] for i in infos])


def test_compute_reward_relabels_and_names_what_it_needs():
    env = gymnasium.make(GOAL_ENV_ID, seed=0).unwrapped
    obs, info = env.reset(seed=0)
    here = obs["achieved_goal"]
    # The goal one has reached: C = 0, the success bonus.
    assert env.compute_reward(here, here, info) == pytest.approx(1.0 + 1000.0)
    crashed = {**info, "collision": True}
    assert env.compute_reward(here, here, crashed) == pytest.approx(1.0 - 200.0 + 1000.0)
    with pytest.raises(ValueError, match="copy_info_dict"):
        env.compute_reward(here[None], here[None], [{}])  # HER without its infos
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 4\)"):
        env.compute_reward(here[:3], here[:3], info)


@pytest.mark.parametrize("flag", ["False", 2, float("nan"), None, np.array([0.0])])
def test_a_collision_flag_is_a_bool_or_refused(flag):
    env = gymnasium.make(GOAL_ENV_ID, seed=0).unwrapped
    obs, info = env.reset(seed=0)
    here = obs["achieved_goal"]
    for compute in (env.compute_reward, env.compute_terminated, env.compute_truncated):
        with pytest.raises(ValueError, match=r"info\['collision'\] must be a bool"):
            compute(here, here, {**info, "collision": flag})
        with pytest.raises(ValueError, match=r"info\['collision'\] must be a bool"):
            compute(here[None], here[None], [{"collision": flag}])
    assert env.compute_reward(here, here, {"collision": np.bool_(True)}) == pytest.approx(801)


def test_every_compute_checks_the_goals_shapes():
    env = gymnasium.make(GOAL_ENV_ID, seed=0).unwrapped
    obs, info = env.reset(seed=0)
    here = obs["achieved_goal"]
    for compute in (env.compute_reward, env.compute_terminated, env.compute_truncated):
        with pytest.raises(ValueError, match=r"shape \(\.\.\., 4\)"):
            compute(np.zeros(5), np.zeros(5), info)  # a (5,) goal
        with pytest.raises(ValueError, match=r"shape \(\.\.\., 4\)"):
            compute(np.zeros((3, 4)), np.zeros((2, 4)), [info] * 3)
        with pytest.raises(ValueError, match="real array"):
            compute(here.astype(np.complex64), here, info)
    ended = env.compute_terminated(np.stack([here] * 3), np.stack([here] * 3), [info] * 3)
    assert ended.tolist() == [True] * 3  # C = 0 < the threshold: success
    assert env.compute_truncated(here, here, info).shape == ()


@pytest.mark.slow
def test_her_replay_buffer_samples_relabelled_goals_with_their_rewards():
    from stable_baselines3 import SAC, HerReplayBuffer

    env = gymnasium.make(GOAL_ENV_ID, seed=0, occupancy=0.0, max_episode_steps=40)
    model = SAC("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer,
                replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future",
                                      "copy_info_dict": True},
                learning_starts=150, batch_size=64, seed=0, device="cpu")
    model.learn(200)
    torch.manual_seed(0)
    np.random.seed(0)
    batch = model.replay_buffer.sample(256)
    desired = batch.observations["desired_goal"].numpy()
    achieved = batch.next_observations["achieved_goal"].numpy()
    stored = model.replay_buffer.next_observations["achieved_goal"][:model.replay_buffer.pos, 0]
    # Most goals are relabelled (4 future goals per real one): achieved goals of the episode.
    relabelled = (desired[:, None, :] == stored[None]).all(-1).any(-1)
    assert relabelled.mean() > 0.5
    # Each reward is Table 1's for its (relabelled) goal, up to the collision penalty.
    no_collision = env.unwrapped.compute_reward(achieved, desired,
                                                [{"collision": False}] * len(desired))
    penalty = batch.rewards[:, 0].numpy() - no_collision
    assert np.isin(np.round(penalty, 3), [0.0, -200.0]).all()


def test_goal_env_takes_no_aids_and_registers_its_episode_limit():
    from torchpark import AidsConfig

    with pytest.raises(TypeError, match="no aids"):
        gymnasium.make(GOAL_ENV_ID, aids=AidsConfig())
    assert gymnasium.spec(GOAL_ENV_ID).max_episode_steps == 1000
    assert gymnasium.spec(ENV_ID).max_episode_steps == 1000


def test_batched_goal_observation_matches_the_single_env():
    from torchpark import ParkingEnv

    env = ParkingEnv(3, seed=4)
    td = env.reset()
    obs = goal_observation(td["observation"], env.state)
    assert {k: tuple(v.shape) for k, v in obs.items()} == {
        "observation": (3, 21), "achieved_goal": (3, 4), "desired_goal": (3, 4)}
    torch.testing.assert_close(obs["desired_goal"][:, :3], env.state.goal)
