"""Stable-Baselines3 on the batched env: :class:`ParkingVecEnv`, an SB3 ``VecEnv`` of N lots
backed by one :class:`~torchpark.env.ParkingEnv` (N), so that ``PPO("MlpPolicy",
ParkingVecEnv(256))`` steps every lot in one batched call instead of N single envs.

    from stable_baselines3 import PPO
    from torchpark.sb3 import ParkingVecEnv

    model = PPO("MlpPolicy", ParkingVecEnv(256, seed=0)).learn(100_000)

Stable-Baselines3 is an optional extra (``pip install -e ".[train]"``); ``import
torchpark`` does not import it. The keywords are those of
``gymnasium.make_vec("torchpark/Parking-v0", ...)`` (:class:`torchpark.gym_env.
ParkingVectorEnv`): ``occupancy``, ``device``, ``seed``, ``compile_step``,
``physical_actions``, ``config``, ``aids``, ``render_mode`` and any ``ParkingConfig`` field.

SB3's conventions: a lot whose episode ends is redrawn in the same step (the returned
observation is the new lot's first); its last observation is in
``infos[i]["terminal_observation"]``, ``infos[i]["TimeLimit.truncated"]`` says it ran out of
steps without ending otherwise (so that SB3 bootstraps its value) and
``infos[i]["is_success"]`` whether it met the paper's success test (SB3 logs the rate as
``rollout/success_rate``). The info dicts of the rows that did not end are empty. One random
generator serves the batch: ``seed(s)`` reseeds it at the next ``reset()``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from torchpark.gym_env import ParkingVectorEnv

try:
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices
except ImportError as err:  # the optional extra
    raise ImportError("torchpark.sb3 needs Stable-Baselines3: pip install -e '.[train]' "
                      "(or pip install stable-baselines3)") from err


class ParkingVecEnv(VecEnv):
    """``num_envs`` parking lots as one Stable-Baselines3 ``VecEnv`` (numpy in and out),
    backed by one ``ParkingEnv(num_envs)`` through :class:`ParkingVectorEnv` (``venv``)."""

    def __init__(self, num_envs: int, **kwargs: Any) -> None:
        self.venv = ParkingVectorEnv(num_envs, **kwargs)
        super().__init__(num_envs, self.venv.single_observation_space,
                         self.venv.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        seed = self._seeds[0]
        obs, _ = self.venv.reset(seed=seed, options=self._options[0] or None)
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return obs

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """The batch's one generator is reseeded with ``seed`` at the next ``reset()``."""
        self._seeds = [seed] * self.num_envs
        return self._seeds

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        if self._actions is None:
            raise RuntimeError("call step_async(actions) before step_wait()")
        obs, reward, terminated, truncated, info = self.venv.step(self._actions)
        self._actions = None
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        ended = np.flatnonzero(dones)  # only the rows that ended carry anything
        if ended.size:
            final_obs, success = info["final_obs"], info["final_info"]["success"]
            for i in ended:
                infos[i] = {"terminal_observation": final_obs[i],
                            "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                            "is_success": bool(success[i])}
        return obs, reward.astype(np.float32), dones, infos

    def close(self) -> None:
        self.venv.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        images = self.venv.render()
        return list(images) if images is not None else [None] * self.num_envs

    # The batch is one object: an attribute or method of "each env" is the batch's.
    def _count(self, indices: VecEnvIndices) -> int:
        return len(self._get_indices(indices))

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.venv, attr_name)] * self._count(indices)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        if self._count(indices) != self.num_envs:
            raise ValueError(f"set_attr({attr_name!r}) sets the batch's attribute: pass no "
                             f"indices (all {self.num_envs} envs share it)")
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result] * self._count(indices)

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False] * self._count(indices)
