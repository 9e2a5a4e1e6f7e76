"""Stable-Baselines3 on the batched env (torchpark.sb3.ParkingVecEnv): SB3's VecEnv contract
(shapes and dtypes, the same step as the Gymnasium vector env, terminal observations and
truncation flags on exactly the rows that ended, one seed for the batch), and SB3's own
wrappers and PPO running on it."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import DummyVecEnv, VecCheckNan, VecEnv, VecMonitor

from torchpark.gym_env import ParkingGymEnv, ParkingVectorEnv
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
    assert env.has_attr("occupancy") and not env.has_attr("dummy")
    assert env.env_is_wrapped(object) == [False] * 4
    with pytest.warns(UserWarning, match="without a render_mode"):  # the batch's own answer
        assert env.env_method("render") == [None] * 4
    with pytest.raises(ValueError, match="acts on the batch's 4 lots at once: pass no indices"):
        env.set_attr("render_envs", 2, indices=[0])
    env.set_attr("render_envs", 2)
    assert env.venv.render_envs == 2
    with pytest.raises(ValueError, match=r"render_envs must be an int >= 1"):
        env.set_attr("render_envs", 0)
    with pytest.raises(RuntimeError, match="step_async"):
        env.step_wait()


def _dummy(n: int, **kwargs) -> DummyVecEnv:
    """SB3's reference: n single envs, each one lot."""
    return DummyVecEnv([lambda i=i: ParkingGymEnv(seed=i, **kwargs) for i in range(n)])


def test_env_method_reset_redraws_only_the_given_rows_as_dummyvecenv_does():
    """Each named row gets a new lot and returns its (observation, info) as a single env's
    reset does; the other rows go on from where they were."""
    env, reference = ParkingVecEnv(4, seed=0, occupancy=0.5), _dummy(4, occupancy=0.5)
    env.reset()
    reference.reset()
    act = actions(4, 3)
    for action in act:
        env.step(action)
        reference.step(action)
    before = env.venv.env.state
    got, expected = env.env_method("reset", indices=[1, 3]), reference.env_method(
        "reset", indices=[1, 3])
    assert len(got) == len(expected) == 2
    for (obs, info), (ref_obs, ref_info) in zip(got, expected, strict=True):
        assert obs.shape == ref_obs.shape and obs.dtype == ref_obs.dtype
        assert info.keys() == ref_info.keys()
        assert all(type(info[k]) is type(ref_info[k]) for k in info)
    after = env.venv.env.state
    kept = torch.tensor([True, False, True, False])
    assert torch.equal(after.pose[kept], before.pose[kept])
    assert torch.equal(after.steps[kept], before.steps[kept]) and (after.steps[~kept] == 0).all()
    np.testing.assert_array_equal(got[0][0], env.venv._td["observation"][1].numpy())
    obs, *_ = env.step(act[0])  # the batch steps on from the partial reset
    assert obs.shape == (4, 23)
    with pytest.raises(IndexError, match=r"indices must be ints in \[0, 4\)"):
        env.env_method("reset", indices=[4])


def test_a_curriculum_written_the_sb3_way_reaches_the_lots():
    """set_attr("occupancy", p) and set_options({"occupancy": p}), as SB3 users write a
    curriculum: the next lots are drawn at p; what the batch cannot take is refused."""
    env = ParkingVecEnv(6, seed=0)
    env.set_attr("occupancy", 0.9)
    assert env.get_attr("occupancy") == [0.9] * 6 and env.venv.env.occupancy == 0.9
    env.reset()
    assert (env.venv.env.state.occupancy == 0.9).all()
    env.set_options([{"occupancy": 0.2}] * 6)  # one dict per env, all equal
    env.reset()
    assert (env.venv.env.state.occupancy == 0.2).all()
    with pytest.raises(ValueError, match="the same for every env"):
        env.set_options([{"occupancy": 0.1}] + [{"occupancy": 0.5}] * 5)
    with pytest.raises(ValueError, match=r"list of 6 dicts"):
        env.set_options([{}] * 2)
    with pytest.raises(ValueError, match="only 'occupancy'"):
        env.set_options({"speed": 1})
    with pytest.raises(AttributeError, match=r"set_attr can set \['occupancy', 'render_envs'\]"):
        env.set_attr("ocupancy", 0.9)  # a typo is not a new attribute nobody reads
    with pytest.raises(ValueError, match="occupancy must be"):
        env.set_attr("occupancy", 1.5)
    with pytest.raises(ValueError, match="acts on the batch's 6 lots at once"):
        env.env_method("close", indices=[0])


def test_step_none_names_the_actions_and_seed_draws_one():
    env = ParkingVecEnv(2, seed=0)
    env.reset()
    with pytest.raises(ValueError, match=r"actions must be an array of shape \(2, 2\)"):
        env.step(None)
    with pytest.raises(ValueError, match="real array"):
        env.step(np.ones((2, 2), np.complex64))
    seeds = env.seed()
    assert len(seeds) == 2 and seeds[0] == seeds[1] and isinstance(seeds[0], int)
    with pytest.raises(ValueError, match="seed must be an int"):
        env.seed(-1)


@pytest.mark.slow
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


def test_sb3s_own_vec_env_corners(tmp_path):
    """The corners of SB3's tests/test_vec_envs.py that a batch can keep: seeding through
    VecNormalize (test_vec_deterministic), seed() giving every env its own lot
    (test_vec_seeding), render() with and without its mode and a warning for another
    (test_vecenv_custom_calls), the wrappers' render_mode (test_render), and
    VecVideoRecorder under PPO (test_video_recorder)."""
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize, VecVideoRecorder

    env = ParkingVecEnv(3, render_mode="rgb_array", render_envs=3, max_episode_steps=30)
    normalised = VecNormalize(env)
    normalised.seed(3)
    first = env.reset()
    normalised.seed(3)
    np.testing.assert_array_equal(env.reset(), first)
    env.seed()
    obs = env.reset()
    assert not np.allclose(obs[0], obs[1]) and not np.allclose(obs[1], obs[2])
    np.testing.assert_array_equal(env.render(mode="rgb_array"), env.render())
    with pytest.warns(UserWarning):
        assert env.render(mode="something_else") is None
    assert VecFrameStack(env, 2).render_mode == VecNormalize(env).render_mode == "rgb_array"
    recorder = VecVideoRecorder(VecNormalize(env), str(tmp_path), video_length=10,
                                record_video_trigger=lambda step: step == 0, name_prefix="lot")
    PPO("MlpPolicy", recorder, n_steps=32, n_epochs=1, device="cpu").learn(96)
    recorder.close()
    assert [p.name for p in tmp_path.glob("*.mp4")] == ["lot-step-0-to-step-10.mp4"]
