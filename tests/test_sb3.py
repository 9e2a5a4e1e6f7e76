"""Stable-Baselines3 on the batched env (torchpark.sb3.ParkingVecEnv): SB3's VecEnv contract
(shapes and dtypes, the same step as the Gymnasium vector env, terminal observations and
truncation flags on exactly the rows that ended, one seed for the batch), and SB3's own
wrappers and PPO running on it."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecCheckNan, VecEnv, VecMonitor

from torchpark.gym_env import ParkingVectorEnv
from torchpark.sb3 import ParkingVecEnv


def actions(n: int, steps: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.uniform(-1, 1, (n, 2)).astype(np.float32) for _ in range(steps)]


def test_the_vec_env_is_the_gymnasium_vector_env_in_sb3s_api():
    """Observations, rewards and dones equal the Gymnasium vector env's on the same seed and
    actions; a row that ended carries its last observation, whether it only ran out of
    steps, and whether it succeeded; the other rows' infos are empty."""
    n = 8
    sb3 = ParkingVecEnv(n, seed=3, max_episode_steps=6)
    gym = ParkingVectorEnv(n, seed=3, max_episode_steps=6)
    assert isinstance(sb3, VecEnv) and sb3.num_envs == n
    assert sb3.observation_space == gym.single_observation_space
    assert sb3.action_space == gym.single_action_space
    obs, (expected, _) = sb3.reset(), gym.reset()
    np.testing.assert_array_equal(obs, expected)
    ended = truncated = 0
    for action in actions(n, 20):
        obs, reward, done, infos = sb3.step(action)
        g_obs, g_reward, g_term, g_trunc, g_info = gym.step(action)
        assert obs.dtype == np.float32 and obs.shape == (n, 23)
        assert reward.dtype == np.float32 and reward.shape == (n,) and done.shape == (n,)
        np.testing.assert_array_equal(obs, g_obs)
        np.testing.assert_array_equal(reward, g_reward)
        np.testing.assert_array_equal(done, g_term | g_trunc)
        assert len(infos) == n
        for i, info in enumerate(infos):
            if not done[i]:
                assert info == {}
                continue
            np.testing.assert_array_equal(info["terminal_observation"], g_info["final_obs"][i])
            assert info["TimeLimit.truncated"] == bool(g_trunc[i] and not g_term[i])
            assert info["is_success"] == bool(g_info["final_info"]["success"][i])
            ended += 1
            truncated += info["TimeLimit.truncated"]
    assert ended and truncated  # episodes ended, some of them at the step limit


def test_one_seed_gives_the_batch_the_same_lots_again():
    env = ParkingVecEnv(4)
    env.seed(11)
    first = env.reset()
    env.step(actions(4, 1)[0])
    env.seed(11)
    np.testing.assert_array_equal(env.reset(), first)
    assert not np.array_equal(env.reset(), first)  # the seed is used once


def test_the_batch_answers_for_every_env():
    env = ParkingVecEnv(4, seed=0)
    assert env.get_attr("num_envs") == [4] * 4 and env.get_attr("num_envs", [1]) == [4]
    assert env.env_is_wrapped(object) == [False] * 4
    with pytest.warns(UserWarning, match="without a render_mode"):  # the batch's own answer
        assert env.env_method("render") == [None] * 4
    with pytest.raises(ValueError, match="sets the batch's attribute: pass no indices"):
        env.set_attr("render_envs", 2, indices=[0])
    env.set_attr("render_envs", 2)
    assert env.venv.render_envs == 2
    with pytest.raises(RuntimeError, match="step_async"):
        env.step_wait()


def test_sb3s_wrappers_and_ppo_run_on_it():
    env = VecMonitor(VecCheckNan(ParkingVecEnv(16, seed=0, max_episode_steps=20),
                                 raise_exception=True))
    model = PPO("MlpPolicy", env, n_steps=32, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(1024)
    assert model.num_timesteps == 1024
    assert model.ep_info_buffer and model.ep_success_buffer  # episodes ended and were logged
    mean, _ = evaluate_policy(model, env, n_eval_episodes=16)
    assert np.isfinite(mean)


def test_rendering_goes_through_the_batch():
    env = ParkingVecEnv(3, seed=0, render_mode="rgb_array", render_envs=2)
    env.reset()
    images = env.get_images()
    assert len(images) == 2 and images[0].dtype == np.uint8 and images[0].ndim == 3
