"""Stable-Baselines3 on the batched env: :class:`ParkingVecEnv`, an SB3 ``VecEnv`` of N lots
backed by one :class:`~torchpark.env.ParkingEnv` (N), so that ``PPO("MlpPolicy",
ParkingVecEnv(256))`` steps every lot in one batched call instead of N single envs.

    from stable_baselines3 import PPO
    from torchpark.sb3 import ParkingVecEnv

    model = PPO("MlpPolicy", ParkingVecEnv(256, seed=0)).learn(100_000)

Stable-Baselines3 is an optional extra (``pip install "torchpark[sb3]"``); ``import
torchpark`` does not import it. The keywords are those of
``gymnasium.make_vec("torchpark/Parking-v0", ...)``
(:class:`~torchpark.gym_env.ParkingVectorEnv`): ``occupancy``, ``device``, ``seed``,
``compile_step``, ``physical_actions``, ``config``, ``aids``, ``render_mode`` and any
``ParkingConfig`` field.

SB3's conventions: a lot whose episode ends is redrawn in the same step (the returned
observation is the new lot's first); its last observation is in
``infos[i]["terminal_observation"]``, ``infos[i]["TimeLimit.truncated"]`` says it ran out of
steps without ending otherwise (so that SB3 bootstraps its value) and
``infos[i]["is_success"]`` whether it met the paper's success test (SB3 logs the rate as
``rollout/success_rate``). The info dicts of the rows that did not end are empty. One random
generator serves the batch: ``seed(s)`` reseeds it at the next ``reset()``. What SB3's
per-env methods (``env_method``, ``get_attr``, ``set_attr``, ``set_options``) mean for one
batch: :class:`ParkingVecEnv`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from torchpark.config import check_seed, is_integer
from torchpark.gym_env import ParkingVectorEnv

try:
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices
except ImportError as err:  # the optional extra
    raise ImportError("torchpark.sb3 needs Stable-Baselines3: pip install 'torchpark[sb3]' "
                      "(in a checkout: pip install -e '.[sb3]')") from err


class ParkingVecEnv(VecEnv):
    """``num_envs`` parking lots as one Stable-Baselines3 ``VecEnv`` (numpy in and out),
    backed by one ``ParkingEnv(num_envs)`` through :class:`ParkingVectorEnv` (``venv``).

    What SB3's per-env methods mean for one batch (``DummyVecEnv`` over single envs is the
    reference where the batch can do the same):

    - ``env_method("reset", indices=...)`` draws new lots for those rows only and returns
      each one's ``(observation, info)``, as the single envs' ``reset`` would (``seed=`` is
      the batch's one generator's); ``env_method("render", indices=...)`` each row's
      picture. Any other method is the batch's: called once, for every env (other indices
      are refused), its result repeated per env.
    - ``get_attr`` reads the batch's attribute, one value per index; ``set_attr`` sets one
      the batch has (``occupancy``: lots drawn from the next reset on; ``render_envs``),
      for every env at once: another name, or indices short of all envs, is refused.
    - ``set_options`` takes one dict, or one per env all equal (one occupancy for the
      batch); ``seed(s)`` reseeds the batch's one generator at the next ``reset()``
      (``seed()``: a random seed, as SB3 draws one) and returns ``[s] * num_envs``.
    """

    def __init__(self, num_envs: int, **kwargs: Any) -> None:
        self.venv = ParkingVectorEnv(num_envs, **kwargs)
        super().__init__(num_envs, self.venv.single_observation_space,
                         self.venv.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        obs, info = self.venv.reset(seed=self._seeds[0], options=self._options[0] or None)
        self.reset_infos = _rows(info, range(self.num_envs))
        self._reset_seeds()
        self._reset_options()
        return obs

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """The batch's one generator is reseeded with ``seed`` (a random one for None, as
        SB3 does) at the next ``reset()``; returns it once per env."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seeds = [check_seed(seed, "seed")] * self.num_envs
        return self._seeds

    def set_options(self, options: list[dict] | dict | None = None) -> None:
        """Options for the next ``reset()``: one dict (``{"occupancy": p}``), or one per env,
        all equal, since the batch draws its lots at one occupancy."""
        if options is None or isinstance(options, dict):
            options = [dict(options or {})] * self.num_envs
        if not isinstance(options, (list, tuple)) or len(options) != self.num_envs \
                or not all(isinstance(o, dict) for o in options):
            raise ValueError(f"options must be a dict, or a list of {self.num_envs} dicts (one "
                             f"per env), got {options!r}")
        if any(o != options[0] for o in options):
            raise ValueError("options must be the same for every env (the batch draws its lots "
                             "at one occupancy): pass one dict")
        extra = sorted(options[0].keys() - {"occupancy"})
        if extra:
            raise ValueError(f"options may hold only 'occupancy', got {extra}")
        super().set_options([dict(options[0]) for _ in range(self.num_envs)])

    def step_async(self, actions: np.ndarray) -> None:
        if actions is None:
            raise ValueError(f"actions must be an array of shape ({self.num_envs}, 2), got None")
        self._actions = actions

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        if self._actions is None:
            raise RuntimeError("call step_async(actions) before step_wait()")
        actions, self._actions = self._actions, None
        obs, reward, terminated, truncated, info = self.venv.step(actions)
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

    def _indices(self, indices: VecEnvIndices) -> list[int]:
        """SB3's indices (None: all, an int, an iterable of ints) as a list, each checked."""
        rows = list(self._get_indices(indices))
        if not all(is_integer(i) and -self.num_envs <= i < self.num_envs for i in rows):
            raise IndexError(f"indices must be ints in [0, {self.num_envs}), got {indices!r}")
        return [int(i) % self.num_envs for i in rows]

    def _all(self, what: str, indices: VecEnvIndices) -> list[int]:
        """``indices`` for an act of the whole batch: ValueError unless they name every env."""
        rows = self._indices(indices)
        if sorted(set(rows)) != list(range(self.num_envs)):
            raise ValueError(f"{what} acts on the batch's {self.num_envs} lots at once: pass no "
                             f"indices (or all of them)")
        return rows

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.venv, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self._all(f"set_attr({attr_name!r})", indices)
        if attr_name not in SETTABLE:
            raise AttributeError(f"set_attr can set {list(SETTABLE)} of the batch, not "
                                 f"{attr_name!r} (it would be taken by nothing)")
        setattr(self.venv, attr_name, value)  # checked by the batch's own setter

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        if method_name == "reset":
            return self._reset_rows(self._indices(indices), *method_args, **method_kwargs)
        if method_name == "render" and not method_args and not method_kwargs:
            rows = self._indices(indices)
            if self.venv.render_mode is None:
                self.venv.render()  # Gymnasium's warning
                return [None] * len(rows)
            return [self.venv.env.render(i) for i in rows]
        rows = self._all(f"env_method({method_name!r})", indices)
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result] * len(rows)

    def _reset_rows(self, rows: list[int], seed: int | None = None,
                    options: dict[str, Any] | None = None) -> list[tuple[np.ndarray, dict]]:
        """The single envs' ``reset(seed, options)`` for ``rows``: new lots for those rows
        only (a seed reseeds the batch's generator first)."""
        if not rows:
            return []
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[rows] = True
        obs, info = self.venv.reset(seed=seed, options={**(options or {}), "reset_mask": mask})
        return list(zip([obs[i] for i in rows], _rows(info, rows), strict=True))

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(self._indices(indices))


# The batch's attributes set_attr sets: what the next reset's lots are drawn at, how many
# lots get_images pictures.
SETTABLE = ("occupancy", "render_envs")


def _rows(info: dict[str, Any], rows: Sequence[int]) -> list[dict[str, Any]]:
    """A Gymnasium vector info (arrays of N, each with its ``_`` mask) as one dict per row of
    ``rows``, as the single env's info: the keys whose mask holds the row, numbers as Python
    numbers."""
    keys = [k for k in info if f"_{k}" in info]
    return [{k: info[k][i].item() if np.ndim(info[k][i]) == 0 else info[k][i]
             for k in keys if info[f"_{k}"][i]} for i in rows]
