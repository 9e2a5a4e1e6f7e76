"""Pictures: the picture shows what the state holds, grids tile pictures, bad indices are errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchpark import ParkingEnv
from torchpark.media.palette import EGO, GOAL, PARKED
from torchpark.media.rendering import LotRenderer, picture_grid


def colour_count(picture: np.ndarray, colour: tuple[int, int, int]) -> int:
    return int((picture == np.array(colour, np.uint8)).all(-1).sum())


@pytest.fixture(scope="module")
def env() -> ParkingEnv:
    env = ParkingEnv(3, seed=0)
    env.occupancy = 0.5
    env.reset()
    return env


def test_frame_is_rgb_uint8_of_the_lot(env):
    picture = env.render(1)
    renderer = LotRenderer(env.layout, env.config)
    assert picture.shape == renderer.shape and picture.dtype == np.uint8
    # 10 px/m: the lot and its 1 m walls, 47.3 m x 37.1 m.
    assert picture.shape == (372, 473, 3)


def test_frame_draws_goal_cars_and_ego(env):
    renderer = LotRenderer(env.layout, env.config, lidar=False)
    s = env.layout.num_slots
    pose = env.state.pose[0].numpy()
    empty = renderer.picture(np.zeros(s, bool), 0, pose)
    full = renderer.picture(np.arange(s) != 0, 0, pose)
    other_goal = renderer.picture(np.zeros(s, bool), 5, pose)
    car_px = colour_count(full, PARKED)
    assert colour_count(empty, PARKED) == 0
    # 37 cars of 2 m x 5 m at 100 px/m^2 (edge pixels included), less what the ego covers.
    assert 0.8 * 37 * 1000 < car_px <= 37 * 1000 * 1.15
    assert colour_count(empty, GOAL) > 0.8 * 2.5 * 5.5 * 100
    assert not np.array_equal(empty, other_goal)
    assert colour_count(empty, EGO) > 0.7 * 2 * 5 * 100


def test_ego_moves_with_the_pose(env):
    renderer = LotRenderer(env.layout, env.config, lidar=False)
    parked = np.zeros(env.layout.num_slots, bool)
    a = renderer.picture(parked, 0, np.array([20.0, 15.0, 0.0]))
    b = renderer.picture(parked, 0, np.array([25.0, 15.0, 0.0]))
    cols_a = np.flatnonzero((a == EGO).all(-1).any(0))
    cols_b = np.flatnonzero((b == EGO).all(-1).any(0))
    assert cols_b.mean() - cols_a.mean() == pytest.approx(50, abs=1)  # 5 m at 10 px/m


def test_grid_tiles_frames(env):
    grid = env.render_grid(columns=2)
    h, w, _ = env.render(0).shape
    assert grid.shape == (2 * h + 4, 2 * w + 4, 3)
    np.testing.assert_array_equal(grid[:h, w + 4:], env.render(1))
    np.testing.assert_array_equal(grid[h + 4:, w + 4:], 255)  # the empty fourth cell


def test_render_follows_the_state(env):
    before = env.render(2)
    env.step(env.full_action_spec.zero().update({"action": torch.tensor([[2.0, 0.3]] * 3)}))
    assert not np.array_equal(before, env.render(2))


@pytest.mark.parametrize("index", [-1, 3, 1.0, True])
def test_bad_index_is_an_error(env, index):
    with pytest.raises(IndexError, match=r"index must be an int in \[0, 2\]"):
        env.render(index)


def test_bad_grid_input_is_an_error(env):
    with pytest.raises(IndexError, match="indices"):
        env.render_grid([0, 7])
    with pytest.raises(ValueError, match="one shape"):
        picture_grid([np.zeros((2, 2, 3), np.uint8), np.zeros((3, 2, 3), np.uint8)])


def test_a_grid_is_bounded_and_named_before_it_is_drawn():
    env = ParkingEnv(2, seed=0)
    env.reset()
    for columns in (100000, 0, 1.5, "2", True):
        with pytest.raises(ValueError, match=r"columns must be an int in \[1, 2\]"):
            env.render_grid(columns=columns)
    with pytest.raises(TypeError, match="indices must be a sequence of env indices"):
        env.render_grid(2)
    assert env.render_grid(np.array([1, 0]), columns=1).shape[0] > env.render(0).shape[0]
