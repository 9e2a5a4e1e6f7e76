"""Rollout videos: one episode, the frames the env shows, GIF and MP4 files, bad paths."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModule

from torchpark import ParkingEnv
from torchpark.media.recording import record_video, rollout_frames, write_video


def forward(observation: torch.Tensor) -> torch.Tensor:
    return torch.tensor([[3.0, 0.2]]).expand(observation.shape[0], 2)


def test_frames_cover_one_episode_of_the_index():
    env = ParkingEnv(3, seed=2, config=None)
    env.occupancy = 0.8
    frames = rollout_frames(env, forward, index=2, max_steps=200)
    steps = int(env.state.steps[2])
    assert len(frames) == steps + 1  # the reset, then one per step
    assert env.state.steps[2] < 200  # it ended (a crash at 3 m/s), not the step budget
    np.testing.assert_array_equal(frames[-1], env.render(2))


def test_torchrl_policy_and_callable_give_the_same_video():
    module = TensorDictModule(forward, in_keys=["observation"], out_keys=["action"])
    a = rollout_frames(ParkingEnv(2, seed=5), forward, max_steps=30)
    b = rollout_frames(ParkingEnv(2, seed=5), module, max_steps=30)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_video_files_hold_the_frames(tmp_path, suffix):
    path = record_video(ParkingEnv(1, seed=0), forward, tmp_path / f"run{suffix}", max_steps=12)
    frames = iio.imread(path, index=None)
    assert frames.shape[0] >= 2 and frames.shape[-1] == 3


def test_bad_video_arguments_are_errors(tmp_path):
    frame = np.zeros((4, 4, 3), np.uint8)
    with pytest.raises(ValueError, match="must end in one of"):
        write_video([frame], tmp_path / "run.avi")
    with pytest.raises(ValueError, match="at least one frame"):
        write_video([], tmp_path / "run.gif")
    with pytest.raises(ValueError, match="fps must be > 0"):
        write_video([frame], tmp_path / "run.gif", fps=0)
    with pytest.raises(TypeError, match="must be a ParkingEnv"):
        rollout_frames(object(), forward)
