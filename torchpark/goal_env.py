"""The goal-conditioned variant, ``gymnasium.make("torchpark/ParkingGoal-v0")``: the paper's
task with a ``Dict`` observation (``observation``, ``achieved_goal``, ``desired_goal``) and a
vectorised ``compute_reward``, the interface of Gymnasium-Robotics' ``GoalEnv`` that
Stable-Baselines3's ``HerReplayBuffer`` relabels with:

    from stable_baselines3 import SAC, HerReplayBuffer

    SAC("MultiInputPolicy", gymnasium.make("torchpark/ParkingGoal-v0"),
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={"copy_info_dict": True})  # the reward's collision term

A goal is the rear axle's pose and speed, ``(x m, y m, psi rad, v m/s)`` (``GOAL_FIELDS``):
``achieved_goal`` the car's, ``desired_goal`` the goal slot's pose at rest. Kept as the
simulator holds them (psi in (-pi, pi], not cos/sin), so that ``compute_reward`` computes
the paper's cost and reward with the simulator's own functions on the same float32 numbers:
it equals the env's reward on real transitions to the last bit, batched or one goal at a
time (the cube root is correctly rounded, :func:`~torchpark.sim.reward.cube_root`;
``tests/test_goal_env.py``). The
``observation`` is what does not depend on the goal: ``[x, y, cos psi, sin psi, v,
lidar_0 ... lidar_15]`` (the LIDAR / max_range, as in the paper's observation).

The reward is Table 1's: ``(1 - cbrt(C)) - 200 [collision] + 1000 [C < 4e-4]`` with C the
pose cost between the two goals. A collision does not depend on the goal: it is carried in
``info["collision"]``, so HER's buffer must keep the infos (``copy_info_dict=True``;
``compute_reward`` says so when they are missing). ``info["is_success"]`` is the paper's
success (SB3 logs its rate). Everything else (keywords, actions, ends) is
``torchpark/Parking-v0``'s (:class:`~torchpark.gym_env.ParkingGymEnv`), without the
agent-side aids: the reward is the paper's.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDictBase
from torch import Tensor

from torchpark.config import ParkingConfig
from torchpark.gym_env import GOAL_ENV_ID, ParkingGymEnv
from torchpark.sim.observation import NAV_DIM
from torchpark.sim.reward import is_success, parking_cost, parking_reward
from torchpark.sim.state import ParkingState

__all__ = ["GOAL_ENV_ID", "GOAL_FIELDS", "ParkingGoalEnv", "goal_cost", "goal_observation",
           "goal_reward"]

GOAL_FIELDS = ("x", "y", "psi", "v")
# The goal-free part of the paper's observation kept in ``observation``: cos psi, sin psi, v.
_HEADING_SPEED = slice(2, 5)


def goal_observation(observation: Tensor, state: ParkingState) -> dict[str, Tensor]:
    """The goal env's observation of N lots from the paper's observation (N, NAV_DIM +
    n_rays) and the state it was observed in: ``observation`` (N, 5 + n_rays) =
    [x, y, cos psi, sin psi, v, lidar], ``achieved_goal`` (N, 4) = (x, y, psi, v) and
    ``desired_goal`` (N, 4) = (goal x, goal y, goal heading, 0); metres, radians, m/s."""
    pose, goal = state.pose, state.goal
    return {
        "observation": torch.cat((pose[:, :2], observation[:, _HEADING_SPEED],
                                  observation[:, NAV_DIM:]), dim=-1),
        "achieved_goal": torch.cat((pose, state.speed[:, None]), dim=-1),
        "desired_goal": torch.cat((goal, torch.zeros_like(state.speed)[:, None]), dim=-1),
    }


def goal_cost(achieved: Tensor, desired: Tensor, cfg: ParkingConfig) -> Tensor:
    """The paper's C between goals [..., 4] = (x, y, psi, v): C = w_x |dx| + w_y |dy| +
    w_alpha |wrap(psi_d - psi_a)| + w_v |v_a - v_d|; [...]. With ``desired`` at rest (the
    env's goals) it is the env's own C."""
    dx = desired[..., 0] - achieved[..., 0]
    dy = desired[..., 1] - achieved[..., 1]
    dv = achieved[..., 3] - desired[..., 3]
    return parking_cost(dx, dy, achieved[..., 2], desired[..., 2], dv, cfg.reward)


def goal_reward(achieved: Tensor, desired: Tensor, collision: Tensor, cfg: ParkingConfig,
                threshold: float) -> Tensor:
    """Table 1's reward [...] for reaching ``achieved`` when ``desired`` was asked (goals
    [..., 4]), with ``collision`` [...] bool: success is C < ``threshold``."""
    cost = goal_cost(achieved, desired, cfg)
    return parking_reward(cost, collision, is_success(cost, threshold), cfg.reward)


def _flag(value: Any) -> np.ndarray:
    """One ``info["collision"]``: a bool, or a bool array (a vector env's infos); anything
    else (a string, an int, a float, NaN) is no flag."""
    flags = np.asarray(value)
    if flags.dtype != np.bool_:
        raise ValueError(f"info['collision'] must be a bool (or a bool array), got "
                         f"{value!r} ({type(value).__name__})")
    return flags


def _collisions(info: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``info["collision"]`` of one info dict, or of each of a sequence of them (SB3's HER
    buffer passes one per relabelled transition), as a bool array of ``shape``."""
    missing = ("compute_reward needs info['collision'] (the paper's reward has a collision "
               "term): with Stable-Baselines3's HerReplayBuffer pass "
               "replay_buffer_kwargs={'copy_info_dict': True}")
    if isinstance(info, Mapping):
        if "collision" not in info:
            raise ValueError(missing)
        flags = _flag(info["collision"])
    elif isinstance(info, (Sequence, np.ndarray)) and not isinstance(info, (str, bytes)):
        if not all(isinstance(i, Mapping) and "collision" in i for i in info):
            raise ValueError(missing)
        each = [_flag(i["collision"]) for i in info]
        if any(f.shape != () for f in each):
            raise ValueError("info['collision'] of each info in a sequence must be one bool")
        flags = np.array([bool(f) for f in each], dtype=bool).reshape(len(each))
    else:
        raise ValueError(f"info must be an info dict or a sequence of them, got "
                         f"{type(info).__name__}")
    try:
        return np.broadcast_to(flags, shape)
    except ValueError:
        raise ValueError(f"info's collision flags have shape {flags.shape}, the goals' batch "
                         f"{shape}") from None


def _goals(achieved_goal: Any, desired_goal: Any) -> tuple[Tensor, Tensor]:
    """Both goals as float32 tensors of one shape (..., 4); ValueError naming them
    otherwise (a wrong shape, a complex, string or object array)."""
    goals = []
    for name, goal in (("achieved_goal", achieved_goal), ("desired_goal", desired_goal)):
        array = np.asarray(goal)
        if array.dtype.kind not in "fiu":
            raise ValueError(f"{name} must be a real array of shape (..., 4) = {GOAL_FIELDS}, "
                             f"got dtype {array.dtype}")
        goals.append(torch.as_tensor(array.astype(np.float32)))
    achieved, desired = goals
    if achieved.shape[-1:] != (4,) or desired.shape != achieved.shape:
        raise ValueError(f"achieved_goal and desired_goal must both have shape (..., 4) "
                         f"= {GOAL_FIELDS}, got {tuple(achieved.shape)} and "
                         f"{tuple(desired.shape)}")
    return achieved, desired


class ParkingGoalEnv(ParkingGymEnv):
    """One parking lot as a goal-conditioned Gymnasium env (see the module's docstring)."""

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        if "aids" in kwargs:
            raise TypeError("ParkingGoalEnv takes no aids: its reward is the paper's, which "
                            "compute_reward reproduces (use torchpark/Parking-v0 for aids)")
        super().__init__(render_mode, **kwargs)
        paper = self.observation_space
        if not isinstance(paper, spaces.Box):
            raise TypeError(f"the paper's observation space must be a Box, got {paper!r}")
        low, high = paper.low, paper.high  # dx, dy bound x, y the same way
        pose_high = np.array([high[0], high[1], np.pi, high[4]], np.float32)
        goal = spaces.Box(-pose_high, pose_high, dtype=np.float32)
        keep = np.r_[0:2, _HEADING_SPEED.start:_HEADING_SPEED.stop, NAV_DIM:len(low)]
        self.observation_space = spaces.Dict({
            "observation": spaces.Box(low[keep], high[keep], dtype=np.float32),
            "achieved_goal": goal, "desired_goal": goal})

    def _observe(self, td: TensorDictBase) -> dict[str, np.ndarray]:
        obs = goal_observation(td["observation"], self.env.state)
        return {key: value[0].cpu().numpy() for key, value in obs.items()}

    def _info(self, td: TensorDictBase) -> dict[str, Any]:
        info = super()._info(td)
        return {**info, "is_success": info["success"]}

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                       info: Mapping[str, Any] | Sequence[Mapping[str, Any]]) -> np.ndarray:
        """Table 1's reward for reaching ``achieved_goal`` when ``desired_goal`` was asked,
        goals (..., 4) = (x, y, psi, v); ``info``: the step's info dict (or one per goal),
        whose ``collision`` adds the penalty. float32 array of the goals' batch shape (0-d for
        one goal): the env's own reward for the env's own goals, bit for bit."""
        achieved, desired = _goals(achieved_goal, desired_goal)
        collision = torch.from_numpy(_collisions(info, tuple(achieved.shape[:-1])).copy())
        reward = goal_reward(achieved, desired, collision, self.env.config,
                             self.env.success_threshold)
        return reward.numpy()

    def compute_terminated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                           info: Mapping[str, Any] | Sequence[Mapping[str, Any]]) -> np.ndarray:
        """Whether the episode ends: success (C < the threshold) or a collision; bool array of
        the goals' batch shape, the goals and infos checked as :meth:`compute_reward` checks
        them."""
        achieved, desired = _goals(achieved_goal, desired_goal)
        collision = _collisions(info, tuple(achieved.shape[:-1]))
        cost = goal_cost(achieved, desired, self.env.config)
        return is_success(cost, self.env.success_threshold).numpy() | collision

    def compute_truncated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                          info: Mapping[str, Any] | Sequence[Mapping[str, Any]]) -> np.ndarray:
        """Whether the episode is cut short: never by the goals (the step limit is Gymnasium's
        ``TimeLimit``'s), so False, a bool array of the goals' batch shape, the goals and
        infos checked as :meth:`compute_reward` checks them."""
        achieved, _ = _goals(achieved_goal, desired_goal)
        return np.zeros_like(_collisions(info, tuple(achieved.shape[:-1])))
