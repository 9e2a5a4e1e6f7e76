"""The Gymnasium interface: registration, spaces, checks, autoreset, determinism, bad input."""

from __future__ import annotations

import sys
import warnings

import gymnasium
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from gymnasium.wrappers.vector import RecordEpisodeStatistics

import torchpark
from torchpark import ENV_ID, ParkingGymEnv, ParkingVectorEnv, RewardConfig


def scripted(steps: int) -> np.ndarray:
    """Smooth actions in the normalised Box."""
    t = np.arange(steps, dtype=np.float32)
    return np.stack((0.6 * np.sin(t / 7.0), 0.9 * np.cos(t / 5.0)), axis=-1).astype(np.float32)


def test_make_gives_single_env_with_the_paper_spaces():
    env = gymnasium.make(ENV_ID)
    assert isinstance(env.unwrapped, ParkingGymEnv)
    assert env.observation_space.shape == (23,)
    assert env.observation_space.dtype == np.float32
    np.testing.assert_array_equal(env.action_space.low, np.float32([-1.0, -1.0]))
    np.testing.assert_array_equal(env.action_space.high, np.float32([1.0, 1.0]))
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert set(info) == {"success", "collision", "occupancy"}
    paper = gymnasium.make(ENV_ID, physical_actions=True)
    np.testing.assert_array_equal(paper.action_space.low, np.float32([-5.0, -0.785]))
    np.testing.assert_array_equal(paper.action_space.high, np.float32([5.0, 0.785]))


def test_normalised_actions_map_linearly_onto_the_papers():
    normalised, physical = ParkingGymEnv(seed=2), ParkingGymEnv(seed=2, physical_actions=True)
    normalised.reset(seed=2), physical.reset(seed=2)
    for u in scripted(20):
        a = normalised.step(u)[0]
        b = physical.step(u * np.float32([5.0, 0.785]))[0]
        np.testing.assert_array_equal(a, b)
    with pytest.raises(TypeError, match="physical_actions must be a bool"):
        ParkingGymEnv(physical_actions="yes")


def test_gymnasium_and_sb3_checkers_pass_without_a_warning():
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gymnasium.make(ENV_ID, render_mode="rgb_array", occupancy=0.5).unwrapped
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
        sb3_check_env(env)
    assert not caught, [str(w.message) for w in caught]


def test_single_env_episode_ends_as_gymnasium_defines():
    env = gymnasium.make(ENV_ID, max_episode_steps=30, occupancy=0.0)
    env.reset(seed=4)
    ends = []
    for _ in range(30):
        _, reward, terminated, truncated, info = env.step(np.zeros(2, np.float32))
        assert isinstance(reward, float)
        ends.append((terminated, truncated))
    # Standing still: neither crash nor success; the time limit truncates step 30 only.
    assert ends == [(False, False)] * 29 + [(False, True)]
    assert info["occupancy"] == 0.0 and not info["success"] and not info["collision"]


def test_make_kwargs_reach_the_batched_env():
    env = gymnasium.make(ENV_ID, occupancy=0.9, reward=RewardConfig(collision_penalty=-1e3),
                         device="cpu")
    assert env.spec.max_episode_steps == 1000  # the paper's limit, Gymnasium's TimeLimit
    env = env.unwrapped
    assert env.env.occupancy == 0.9 and env.env.config.reward.collision_penalty == -1e3
    assert ParkingGymEnv(max_episode_steps=7).env.config.max_steps == 7  # built directly
    vec = gymnasium.make_vec(ENV_ID, num_envs=2, max_episode_steps=9)
    assert vec.env.config.max_steps == 9
    assert gymnasium.make_vec(ENV_ID, num_envs=2).env.config.max_steps == 1000
    with pytest.raises(TypeError, match="max_episode_steps"):
        gymnasium.make(ENV_ID, max_steps=7)  # ParkingConfig's name: the spec would not say it
    for bad in (True, 0, "5"):
        with pytest.raises(ValueError, match="max_episode_steps must be an int >= 1"):
            ParkingGymEnv(max_episode_steps=bad)
    _, info = env.reset(seed=1)
    assert info["occupancy"] == pytest.approx(0.9)
    _, info = env.reset(options={"occupancy": 0.2})
    assert info["occupancy"] == pytest.approx(0.2)


def test_same_seed_same_observations_and_frames():
    envs = [gymnasium.make(ENV_ID, render_mode="rgb_array", occupancy=0.6) for _ in range(2)]
    runs = []
    for env in envs:
        obs, _ = env.reset(seed=123)
        seen, frames = [obs], [env.render()]
        for action in scripted(40):
            obs, _, terminated, truncated, _ = env.step(action)
            seen.append(obs)
            frames.append(env.render())
            if terminated or truncated:
                obs, _ = env.reset()
        runs.append((np.stack(seen), np.stack(frames)))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    other, _ = envs[0].reset(seed=124)
    assert not np.array_equal(other, runs[0][0][0])


def test_make_vec_is_one_batched_env():
    env = gymnasium.make_vec(ENV_ID, num_envs=32)
    assert isinstance(env, ParkingVectorEnv) and env.env.num_envs == 32
    assert env.metadata["autoreset_mode"] == gymnasium.vector.AutoresetMode.SAME_STEP
    assert env.observation_space == gymnasium.vector.utils.batch_space(
        env.single_observation_space, 32)
    assert env.action_space == gymnasium.vector.utils.batch_space(env.single_action_space, 32)
    obs, info = env.reset(seed=0)
    assert obs.shape == (32, 23) and obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    env.action_space.seed(0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert (reward.shape, terminated.shape, truncated.shape) == ((32,), (32,), (32,))
    assert terminated.dtype == truncated.dtype == np.bool_
    assert info["success"].shape == (32,) and info["_success"].all()


def test_vector_autoreset_matches_single_env_reset_by_hand():
    """SAME_STEP: the step that ends an episode returns the next lot's first observation and
    keeps the last one in info["final_obs"]; N = 1 vector == single env reset by hand."""
    vec = gymnasium.make_vec(ENV_ID, num_envs=1, max_episode_steps=15, occupancy=0.5)
    single = gymnasium.make(ENV_ID, max_episode_steps=15, occupancy=0.5)
    v_obs, _ = vec.reset(seed=9)
    s_obs, _ = single.reset(seed=9)
    ends = 0
    for action in scripted(50):
        v_obs, v_rew, v_term, v_trunc, v_info = vec.step(action[None])
        s_obs, s_rew, s_term, s_trunc, s_info = single.step(action)
        assert v_rew[0] == pytest.approx(s_rew) and (v_term[0], v_trunc[0]) == (s_term, s_trunc)
        if s_term or s_trunc:
            ends += 1
            assert v_info["_final_obs"][0]
            np.testing.assert_array_equal(v_info["final_obs"][0], s_obs)
            assert v_info["final_info"]["collision"][0] == s_info["collision"]
            s_obs, _ = single.reset()
        else:
            assert "final_obs" not in v_info
        np.testing.assert_array_equal(v_obs[0], s_obs)
    assert ends >= 3


def test_vector_env_works_with_gymnasium_vector_wrappers():
    env = RecordEpisodeStatistics(gymnasium.make_vec(ENV_ID, num_envs=8, max_episode_steps=10))
    env.reset(seed=0)
    finished = 0
    for _ in range(25):
        _, _, _, _, info = env.step(np.zeros((8, 2), np.float32))
        if "episode" in info:
            finished += int(info["_episode"].sum())
            np.testing.assert_array_equal(info["episode"]["l"][info["_episode"]], 10)
    assert finished == 16


@pytest.mark.parametrize("action, match", [
    (np.float32([5.5, 0.0]), "must lie in"),
    (np.float32([0.0, -1.2]), "must lie in"),
    (np.float32([np.nan, 0.0]), "finite"),
    (np.float32([0.0, np.inf]), "finite"),
    (np.float32([1.0, 0.0, 0.0]), "shape"),
])
def test_single_env_rejects_bad_actions(action, match):
    env = ParkingGymEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.step(action)


def test_vector_env_rejects_bad_actions():
    env = ParkingVectorEnv(4)
    env.reset(seed=0)
    actions = np.zeros((4, 2), np.float32)
    actions[2, 0] = 9.0
    with pytest.raises(ValueError, match=r"must lie in .*\[\[9.0, 0.0\]\]"):
        env.step(actions)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((3, 2), np.float32))
    with pytest.raises(ValueError, match="seed must be one int"):
        env.reset(seed=[1, 2, 3, 4])
    with pytest.raises(RuntimeError, match="reset"):
        ParkingVectorEnv(2).step(np.zeros((2, 2), np.float32))
    with pytest.raises(RuntimeError, match="before reset"):
        ParkingVectorEnv(2, render_mode="rgb_array").render()


def test_bad_construction_is_a_clear_error():
    with pytest.raises(ValueError, match="render_mode must be None or one of"), \
            pytest.warns(UserWarning, match="not in the possible render_modes"):  # Gymnasium's
        gymnasium.make(ENV_ID, render_mode="ansi")
    with pytest.raises(TypeError, match="unknown keyword arguments \\['max_step'\\]"):
        gymnasium.make(ENV_ID, max_step=3)
    with pytest.raises(ValueError, match="occupancy"):
        gymnasium.make(ENV_ID, occupancy=1.5)
    env = ParkingGymEnv()
    with pytest.raises(ValueError, match="options may hold only 'occupancy'"):
        env.reset(options={"density": 0.3})


def test_hostile_construction_and_actions_are_named():
    with pytest.raises(TypeError, match=r"config must be a ParkingConfig or None, got \{\}"):
        gymnasium.make(ENV_ID, config={})
    env = ParkingGymEnv(seed=0)
    env.reset(seed=0)
    assert not env.action_space.contains(np.array([0.5, 0.1j], np.complex64))
    for bad in (np.array([0.5, 0.1j]), ["0.5", "0.1"], None):
        with pytest.raises(ValueError, match="action must be"):  # not taken, as contains says
            env.step(bad)
    with pytest.raises(ValueError, match="device is 'cpu:1', but torch has one CPU device"):
        gymnasium.make(ENV_ID, device="cpu:1")


def test_occupancy_set_on_the_gymnasium_envs_reaches_the_lots():
    """``env.unwrapped.occupancy = p`` (a curriculum's way) is the batched env's occupancy,
    not a new attribute nobody reads."""
    single, vector = ParkingGymEnv(seed=0), ParkingVectorEnv(3, seed=0)
    for env in (single, vector):
        env.occupancy = 0.9
        assert env.env.occupancy == 0.9
        _, info = env.reset()
        assert np.all(info["occupancy"] == np.float32(0.9))
        with pytest.raises(ValueError, match="occupancy"):
            env.occupancy = -0.1
    wrapped = gymnasium.make(ENV_ID, seed=0)  # through Gymnasium's wrappers
    wrapped.set_wrapper_attr("occupancy", 0.6)
    assert wrapped.unwrapped.env.occupancy == 0.6 == wrapped.get_wrapper_attr("occupancy")
    for bad in (0, -2, 1.5, "3"):
        with pytest.raises(ValueError, match="render_envs must be an int >= 1"):
            ParkingVectorEnv(2, render_envs=bad)


def test_the_vector_env_resets_the_rows_of_a_reset_mask():
    """Gymnasium's partial reset (``options={"reset_mask": mask}``): new lots in the masked
    rows, the others as they were, the infos' masks on the reset rows."""
    env = ParkingVectorEnv(4, seed=1, occupancy=0.5)
    env.reset()
    obs, _, _, _, _ = env.step(np.full((4, 2), 0.3, np.float32))
    mask = np.array([False, True, False, True])
    again, info = env.reset(options={"reset_mask": mask, "occupancy": 0.9})
    np.testing.assert_array_equal(again[~mask], obs[~mask])
    assert not np.array_equal(again[mask], obs[mask])
    np.testing.assert_array_equal(info["_occupancy"], mask)
    np.testing.assert_array_equal(info["occupancy"][mask], np.float32(0.9))
    for bad in (mask.astype(int), np.zeros(4, bool), mask[:3]):
        with pytest.raises(ValueError, match=r"reset_mask"):
            env.reset(options={"reset_mask": bad})


def test_registration_is_idempotent():
    torchpark.register()
    assert ENV_ID in gymnasium.registry


@pytest.mark.slow
def test_record_video_wrapper_writes_an_episode(tmp_path):
    from gymnasium.wrappers import RecordVideo  # writes with moviepy, a dev dependency

    folder = tmp_path / "videos"
    env = RecordVideo(gymnasium.make(ENV_ID, render_mode="rgb_array", max_episode_steps=20),
                      video_folder=str(folder), episode_trigger=lambda episode: True,
                      disable_logger=True)
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.float32([1.0, 0.1]))
        done = terminated or truncated
    env.close()
    assert [p.suffix for p in folder.iterdir()] == [".mp4"]


@pytest.mark.slow
def test_stable_baselines3_ppo_trains_on_the_env():
    """The paper's own tool chain: SB3 PPO on torchpark/Parking-v0 for a few thousand steps."""
    from stable_baselines3 import PPO

    env = gymnasium.make(ENV_ID, max_episode_steps=200)
    model = PPO("MlpPolicy", env, n_steps=512, batch_size=128, n_epochs=2, seed=0, device="cpu")
    model.learn(total_timesteps=2048)
    assert model.num_timesteps == 2048
    obs, _ = env.reset(seed=1)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action)


def test_a_step_after_the_episode_ended_asks_for_a_reset():
    """Gymnasium leaves stepping an ended episode undefined; here it is refused by name (the
    car would stay where it collided, and the -200 would be scored again)."""
    env = ParkingGymEnv(max_episode_steps=2)
    with pytest.raises(gymnasium.error.ResetNeeded, match=r"call env\.reset"):
        env.step(np.zeros(2, np.float32))
    env.reset(seed=0)
    results = [env.step(np.zeros(2, np.float32)) for _ in range(2)]
    assert [r[3] for r in results] == [False, True]  # truncated at max_episode_steps
    with pytest.raises(gymnasium.error.ResetNeeded, match="terminated or truncated"):
        env.step(np.zeros(2, np.float32))
    env.reset()
    assert env.step(np.zeros(2, np.float32))[3] is False


def test_human_mode_shows_each_frame_in_a_window(monkeypatch):
    """pygame's own headless display (SDL's dummy video driver) stands in for the screen;
    everything above it runs: the window shows the lot's picture after every reset and step."""
    pygame = pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    env = gymnasium.make(ENV_ID, render_mode="human", seed=0, occupancy=0.5)
    assert env.metadata["render_modes"] == ["rgb_array", "human"]
    env.reset()
    for _ in range(3):
        env.step(env.action_space.sample())
        shown = pygame.surfarray.array3d(pygame.display.get_surface()).swapaxes(0, 1)
        # the lot with the overlay, on in the window by default
        np.testing.assert_array_equal(shown, env.unwrapped.env.render(0,
                                                                      env.unwrapped.readout()))
    assert env.render() is None  # Gymnasium's convention: the window is the output
    env.close()
    assert pygame.display.get_surface() is None


def test_human_mode_without_pygame_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pygame", None)  # import pygame raises ImportError
    with pytest.raises(gymnasium.error.DependencyNotInstalled, match=r"torchpark\[human\]"):
        gymnasium.make(ENV_ID, render_mode="human")
    with pytest.raises(ValueError, match="render_mode"):
        gymnasium.make_vec(ENV_ID, num_envs=2, render_mode="human")  # pictures only


def test_the_picture_says_which_layer_drives_when_aids_are_on():
    from torchpark import AidsConfig, BrakeConfig, DockingConfig, ParkingEnv
    from torchpark.aids.step import drivers

    paper = ParkingEnv(1, seed=0)
    paper.reset()
    assert drivers(AidsConfig(), paper.aid_state) is None  # the paper's env: nothing written
    env = ParkingEnv(2, seed=0, aids=AidsConfig(brake=BrakeConfig(), docking=DockingConfig()))
    env.reset()
    assert drivers(env.aids, env.aid_state) == ["policy", "policy"]
    state = env.state  # row 0 just behind its goal, in the docking law's funnel
    behind = state.goal.clone()
    behind[:, 0] -= 2.0 * torch.cos(behind[:, 2])
    behind[:, 1] -= 2.0 * torch.sin(behind[:, 2])
    td = env.set_state(state._replace(pose=torch.where(torch.tensor([[True], [False]]), behind,
                                                       state.pose)))
    td = env.step(td.set("action", torch.zeros(2, 2)))
    assert td["next", "docking_engaged"][0] and drivers(env.aids, env.aid_state)[0] == "docking law"
    labelled, plain = env.render(0), paper.render(0)
    assert (labelled[3:8, 6:30] == 255).any() and not (plain[3:8, 6:30] == 255).all(-1).any()
