"""The pictures' overlay: its numbers are the env's (the step's output, the observation), it
draws only where asked (on in the window, off in frames by default), and the zoom shows near
the goal only."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from tests.conftest import place
from torchpark import ParkingEnv
from torchpark.gym_env import ParkingGymEnv
from torchpark.media.overlay import (
    MAX_ZOOM,
    ZOOM_PIXELS,
    ZOOM_RADIUS,
    Readout,
    goal_frame_error,
    readout_lines,
    zoom_scale,
)


def step(env: ParkingEnv, action: list[float]) -> TensorDict:
    """One step of env ``env`` (N = 1) at ``action``: what ``step`` returned."""
    return env.step(TensorDict({"action": torch.tensor([action])}, batch_size=[1]))


def test_the_readout_is_what_the_step_returned_and_the_observation_holds():
    env = ParkingEnv(1, seed=3)
    env.occupancy = 0.4
    env.reset()
    for t, action in enumerate(([1.5, 0.3], [-2.0, -0.5], [0.7, 0.1]), start=1):
        td = step(env, action)
        readout, nxt = env.readout(0, td), td["next"]
        obs = nxt["observation"][0].double()
        assert readout.step == t
        assert readout.speed == pytest.approx(obs[4].item(), abs=1e-6)
        assert readout.steer == pytest.approx(action[1], abs=1e-6)
        assert readout.cost == pytest.approx(nxt["cost"].item(), rel=1e-6)
        assert readout.threshold == env.success_threshold
        assert readout.success == nxt["success"].item()
        assert readout.collision == nxt["collision"].item()
        # The observation's goal offset (goal minus axle, world frame) in the goal's frame.
        alpha = math.atan2(obs[6], obs[5])
        psi = math.atan2(obs[3], obs[2])
        along = -(math.cos(alpha) * obs[0] + math.sin(alpha) * obs[1])
        across = math.sin(alpha) * obs[0] - math.cos(alpha) * obs[1]
        assert readout.along == pytest.approx(along.item(), abs=1e-4)
        assert readout.across == pytest.approx(across.item(), abs=1e-4)
        assert readout.heading == pytest.approx(math.remainder(psi - alpha, 2 * math.pi),
                                                abs=1e-5)
    before = env.readout(0)
    assert before.steer is None and not before.success and not before.collision


def test_the_readout_reports_a_collision_and_a_success():
    env = ParkingEnv(1, seed=0)
    env.reset()
    place(env, torch.tensor([env.layout.width - 4.5 - 0.1, 3.0, 0.0]))
    td = step(env, [2.0, 0.0])  # 0.2 m through the right wall
    crash = env.readout(0, td)
    assert crash.collision and not crash.success
    assert "COLLISION" in readout_lines(crash)[1]
    env.reset()
    place(env, env.state.goal)
    parked = env.readout(0, step(env, [0.0, 0.0]))
    assert parked.success and parked.cost < parked.threshold
    assert parked.distance < 1e-6
    lines = readout_lines(parked)
    assert " < " in lines[1] and "PARKED" in lines[1]
    assert "+0.0 mm" in lines[2]


def test_the_lines_write_millimetres_below_a_metre_and_degrees():
    readout = Readout(step=7, speed=-0.25, steer=math.radians(-12.5), cost=0.5, threshold=4e-4,
                      success=False, collision=False, along=0.0123, across=-2.5,
                      heading=math.radians(0.05))
    assert readout_lines(readout) == [
        "step 7   v -0.25 m/s   steer -12.5 deg",
        "C 0.5 >= 0.0004   driving",
        "axle off goal:  along +12.3 mm   across -2.50 m",
        "heading off goal:  +0.05 deg"]


def test_the_goal_frame_error_rotates_into_the_goal_and_wraps_the_heading():
    goal = torch.tensor([[10.0, 5.0, math.pi / 2]])
    pose = torch.tensor([[10.0, 5.5, -math.pi + 0.1]])  # 0.5 m ahead along the goal's heading
    along, across, heading = goal_frame_error(pose, goal)[0].tolist()
    assert along == pytest.approx(0.5) and across == pytest.approx(0.0, abs=1e-6)
    assert heading == pytest.approx(-math.pi / 2 + 0.1 - math.pi + 2 * math.pi, abs=1e-6)


def test_the_zoom_scale_puts_the_axle_a_third_out_within_its_bounds():
    assert zoom_scale(0.01, 10.0) == pytest.approx(ZOOM_PIXELS / 3 / 0.01)
    assert zoom_scale(0.0, 10.0) == MAX_ZOOM
    assert zoom_scale(100.0, 10.0) == 10.0


def test_the_overlay_draws_only_where_asked_and_the_zoom_only_near_the_goal():
    env = ParkingEnv(1, seed=1)
    env.reset()
    plain = env.render(0)
    far = env.render(0, env.readout(0))
    assert env.readout(0).distance > ZOOM_RADIUS
    label = (slice(0, 60), slice(0, 200))  # the top-left corner
    corner = (slice(4, 4 + ZOOM_PIXELS), slice(-4 - ZOOM_PIXELS, -4))  # the top-right one
    assert not np.array_equal(far[label], plain[label])
    np.testing.assert_array_equal(far[corner], plain[corner])
    goal = env.state.goal.clone()
    place(env, goal + torch.tensor([0.002, 0.0, 0.0]))  # 2 mm off
    near, plain = env.render(0, env.readout(0)), env.render(0)
    assert not np.array_equal(near[corner], plain[corner])


def test_a_gym_env_draws_the_overlay_in_frames_only_when_asked():
    quiet = ParkingGymEnv("rgb_array", seed=0)
    loud = ParkingGymEnv("rgb_array", seed=0, overlay=True)
    assert not quiet.overlay and loud.overlay
    quiet.reset(seed=0)
    loud.reset(seed=0)
    action = np.array([0.5, -0.5], np.float32)
    quiet.step(action)
    _, _, _, _, info = loud.step(action)
    assert not np.array_equal(quiet.render(), loud.render())
    readout = loud.readout()
    assert readout.step == 1 and readout.collision == info["collision"]
    assert readout.steer == pytest.approx(-0.5 * loud.env.action_spec.high[0, 1].item())


def test_the_window_shows_the_overlay_by_default():
    pytest.importorskip("pygame")
    assert ParkingGymEnv("human").overlay
    assert not ParkingGymEnv("human", overlay=False).overlay


def test_bad_overlay_arguments_are_refused_by_name():
    with pytest.raises(TypeError, match="overlay"):
        ParkingGymEnv("rgb_array", overlay="yes")
    env = ParkingEnv(2, seed=0)
    env.reset()
    with pytest.raises(ValueError, match=r"tensordict must be what ParkingEnv\.step returned"):
        env.readout(0, TensorDict({}, batch_size=[2]))
    with pytest.raises(IndexError, match="index"):
        env.readout(2)
    with pytest.raises(ValueError, match="readouts must hold one readout per index"):
        env.render_grid([0, 1], readouts=[env.readout(0)])
