"""Gymnasium interface: ``gymnasium.make("torchpark/Parking-v0")`` and
``gymnasium.make_vec("torchpark/Parking-v0", num_envs=N)``, both backed by one batched
:class:`ParkingEnv` (N = 1 for the single env; no loop over N copies for the vector env).

Keyword arguments of ``make``/``make_vec``: ``occupancy``, ``device``, ``seed`` (the initial
seed; ``reset(seed=...)`` reseeds), ``compile_step``, ``physical_actions``, ``config`` (a
:class:`ParkingConfig`), ``aids`` (an :class:`AidsConfig`; None, the paper's env, by default)
and any :class:`ParkingConfig` field (``reward=RewardConfig(...)``), which replaces that
field of ``config``; ``make`` also takes ``overlay`` (the numbers on each picture: on in the
``"human"`` window, off in ``"rgb_array"`` frames by default). The episode limit is
Gymnasium's ``max_episode_steps`` (registered as
the paper's 1,000 steps, which ``spec.max_episode_steps`` says): ``make`` puts Gymnasium's
``TimeLimit`` there, ``make_vec`` passes it to the vector env, and either class built
directly takes it as its own limit (``ParkingConfig.max_steps``, which is not a keyword
here, so that the spec and the env cannot disagree).

Actions: by default the normalised Box [-1, 1]^2 that Gymnasium's ``check_env`` and
Stable-Baselines3 ask for, mapped linearly onto the paper's (v, delta) =
(u0 * max_speed m/s, u1 * max_steer rad), i.e. +-5 m/s and +-0.785 rad. With
``physical_actions=True`` the action Box is the paper's own [-5, 5] m/s x [-0.785, 0.785] rad.
Actions must lie in the action Box and be finite (ValueError otherwise): the torchrl env clamps
out-of-range actions, a Gymnasium env states its bounds instead. Real arrays of any width are
taken (float64 ones, numpy's default, rounded to float32); a complex, string or object array,
which ``action_space.contains`` refuses too, is refused. Observations are the paper's
23 floats (see :class:`ParkingEnv`).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from tensordict import TensorDict, TensorDictBase

from torchpark.aids.config import AidsConfig
from torchpark.aids.step import BRAKED, DOCKING_ENGAGED, INTERVENTIONS, POSITION
from torchpark.checks import check_optional
from torchpark.config import ParkingConfig, check_flag, is_integer
from torchpark.env import ParkingEnv
from torchpark.sim.observation import NAV_DIM

if TYPE_CHECKING:  # Pillow, imported on the first picture
    from torchpark.media.overlay import Readout

ENV_ID = "torchpark/Parking-v0"
GOAL_ENV_ID = "torchpark/ParkingGoal-v0"  # torchpark.goal_env
# The single env also opens a window ("human", through pygame: torchpark[human]); the
# vector env returns pictures only.
RENDER_MODES = ["rgb_array", "human"]
VECTOR_RENDER_MODES = ["rgb_array"]
INFO_KEYS = ("success", "collision", "occupancy")
# What the aids emit, in the info when they are on: the brake's flag and count, the docking
# law's flag, the rear axle's (x, y) (AidsConfig.observe_position).
AID_INFO_KEYS = (BRAKED, INTERVENTIONS, DOCKING_ENGAGED, POSITION)


def _make_batched(num_envs: int, occupancy: float | None, device: torch.device | str,
                  seed: int | None, compile_step: bool, config: ParkingConfig | None,
                  aids: AidsConfig | None, max_episode_steps: int | None,
                  fields: dict[str, Any]) -> ParkingEnv:
    check_optional(config, ParkingConfig, "config")
    config = config if config is not None else ParkingConfig()
    names = {f.name for f in dataclasses.fields(ParkingConfig)}
    if "max_steps" in fields:
        raise TypeError("the episode limit is Gymnasium's max_episode_steps (not max_steps): "
                        "gymnasium.make(..., max_episode_steps=N)")
    if max_episode_steps is not None:  # checked by its own name, then ParkingConfig's range
        if not is_integer(max_episode_steps) or max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be an int >= 1, got "
                             f"{max_episode_steps!r}")
        fields["max_steps"] = int(max_episode_steps)
    unknown = sorted(set(fields) - names)
    if unknown:
        raise TypeError(f"unknown keyword arguments {unknown}: expected occupancy, device, "
                        f"seed, compile_step, physical_actions, config, aids, render_mode, "
                        f"overlay (one env's) or "
                        f"ParkingConfig fields {sorted(names)}")
    config = dataclasses.replace(config, **fields)
    env = ParkingEnv(num_envs, device=device, seed=seed, config=config, aids=aids,
                     compile_step=compile_step)
    if occupancy is not None:
        env.occupancy = occupancy
    return env


def _check_render_mode(render_mode: str | None, modes: list[str]) -> str | None:
    if render_mode is not None and render_mode not in modes:
        raise ValueError(f"render_mode must be None or one of {modes}, got {render_mode!r}")
    return render_mode


def _spaces(env: ParkingEnv, physical_actions: bool
            ) -> tuple[spaces.Box, spaces.Box, torch.Tensor]:
    """The single env's observation and action Boxes (float32), and the factor (2,) from an
    action in the Box to the env's (v m/s, delta rad)."""
    veh, n_rays = env.config.vehicle, env.config.lidar.n_rays
    # The goal lies in the lot; the rear axle lies inside the car's box, which the colliding
    # step moves at most max_speed * dt past a wall's inner face.
    reach = env.config.lot.wall_thickness + veh.max_speed * veh.dt
    reach_x, reach_y = env.layout.width + reach, env.layout.height + reach
    high = np.array([reach_x, reach_y, 1, 1, veh.max_speed, 1, 1] + [1] * n_rays, np.float32)
    low = -high
    low[NAV_DIM:] = 0.0
    observation = spaces.Box(low, high, dtype=np.float32)
    limits = np.array([veh.max_speed, veh.max_steer], np.float32)
    bound = limits if physical_actions else np.ones(2, np.float32)
    action = spaces.Box(-bound, bound, dtype=np.float32)
    scale = torch.from_numpy(limits / bound).to(env.device)
    return observation, action, scale


def _checked_actions(actions: Any, space: spaces.Box, shape: tuple[int, ...],
                     device: torch.device) -> torch.Tensor:
    """numpy-like actions -> float32 tensor, with a clear error for a wrong shape, a
    non-finite value or a value outside the Box."""
    if actions is None:
        raise ValueError(f"action must be an array of shape {shape} = [v m/s, delta rad], "
                         f"got None")
    given = np.asarray(actions)
    if given.dtype.kind not in "biuf":  # as action_space.contains: no complex, no string
        raise ValueError(f"action must be a real array of shape {shape} = [v m/s, delta rad], "
                         f"got dtype {given.dtype}")
    array = given.astype(np.float32)
    if array.shape != shape:
        raise ValueError(f"action must have shape {shape} = [v m/s, delta rad], "
                         f"got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"action must be finite (no NaN or inf), got {array.tolist()}")
    outside = ((array < space.low) | (array > space.high)).reshape(-1, 2).any(-1)
    if outside.any():
        raise ValueError(f"action must lie in the action Box [{space.low.tolist()}, "
                         f"{space.high.tolist()}], got {array.reshape(-1, 2)[outside].tolist()}")
    return torch.from_numpy(array).to(device)


def _reset_lots(env: ParkingEnv, seed: int | None, options: dict[str, Any] | None,
                mask: np.ndarray | None = None, last: TensorDictBase | None = None
                ) -> TensorDictBase:
    """Reseed the env's generator (when ``seed`` is given), apply ``options["occupancy"]``
    (the only option) and draw new lots for the rows of ``mask`` (N,) bool (every row when
    None); the other rows keep what ``last`` (the env's last output) holds for them."""
    options = dict(options or {})
    if options.keys() - {"occupancy"}:
        raise ValueError(f"options may hold only 'occupancy', got {sorted(options)}")
    if seed is not None:
        env.set_seed(seed)
    if "occupancy" in options:
        env.occupancy = options["occupancy"]
    if mask is None:
        return env.reset()
    rows = torch.from_numpy(mask).to(env.device)[:, None]
    given = last.clone() if last is not None else TensorDict(
        batch_size=env.batch_size, device=env.device)
    return env.reset(given.set("_reset", rows))


def _reset_mask(options: dict[str, Any] | None, num_envs: int
                ) -> tuple[dict[str, Any] | None, np.ndarray | None]:
    """Gymnasium's ``options["reset_mask"]`` (a numpy bool array (N,) with a True, as
    ``SyncVectorEnv`` checks it) split from the other options."""
    if not options or "reset_mask" not in options:
        return options, None
    options = dict(options)
    mask = options.pop("reset_mask")
    if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != (num_envs,):
        raise ValueError(f"options['reset_mask'] must be a numpy bool array of shape "
                         f"({num_envs},), got {mask!r}")
    if not mask.any():
        raise ValueError("options['reset_mask'] must hold at least one True")
    return options, mask


def _numpy_info(td: TensorDictBase) -> dict[str, np.ndarray]:
    """success, collision (bool) and occupancy (float32), each (N,), and what the aids emit
    when they are on (AID_INFO_KEYS: (N,) or (N, 2) for the position)."""
    info = {key: td[key][:, 0].cpu().numpy() for key in INFO_KEYS}
    aided = {key: td[key] for key in AID_INFO_KEYS if key in td.keys()}
    return {**info, **{key: (t[:, 0] if key != POSITION else t).cpu().numpy()
                       for key, t in aided.items()}}


def _batch_occupancy() -> property:
    """The ``occupancy`` of a Gymnasium env's batched env (lots drawn from now on)."""
    def get(self: ParkingGymEnv | ParkingVectorEnv) -> float:
        return self.env.occupancy

    def put(self: ParkingGymEnv | ParkingVectorEnv, value: float) -> None:
        self.env.occupancy = value

    return property(get, put, doc="Fraction in [0, 1] of the non-goal slots that hold a parked "
                    "car in lots drawn from the next reset on (:attr:`ParkingEnv.occupancy`; "
                    "settable, as ``reset(options={'occupancy': p})``).")


class ParkingGymEnv(gymnasium.Env):
    """One parking lot as a Gymnasium env (numpy in and out), backed by ``ParkingEnv(1)``.

    ``terminated`` is a collision or a success; ``truncated`` is the step limit
    (``ParkingConfig.max_steps``, 1000) without either. ``info`` holds ``success``,
    ``collision`` (bool) and ``occupancy`` (float, the occupancy the lot was drawn with), and
    with aids on what they emit (``AID_INFO_KEYS``: ``braked``, ``interventions``,
    ``docking_engaged``, ``position``), which an agent trained with them may read.
    ``reset(options={"occupancy": p})`` changes the occupancy of this and later lots.
    ``gymnasium.make`` wraps it in Gymnasium's ``TimeLimit`` at ``spec.max_episode_steps``
    (1,000, the env's own limit; ``max_episode_steps=N`` changes it).
    ``overlay`` writes the step, speed, steering, cost C against the success threshold, the
    outcome and the pose error on each picture, with a zoom near the goal
    (:mod:`torchpark.media.overlay`): on by default in the ``"human"`` window, off in
    ``"rgb_array"`` frames.
    """

    # an attribute of Gymnasium's Env (set per instance below), so no ClassVar
    metadata: dict[str, Any] = {"render_modes": RENDER_MODES, "render_fps": 10}  # noqa: RUF012
    occupancy = _batch_occupancy()

    def __init__(self, render_mode: str | None = None, *, occupancy: float | None = None,
                 device: torch.device | str = "cpu", seed: int | None = None,
                 compile_step: bool = False, physical_actions: bool = False,
                 config: ParkingConfig | None = None, aids: AidsConfig | None = None,
                 max_episode_steps: int | None = None, overlay: bool | None = None,
                 **fields: Any) -> None:
        self.render_mode = _check_render_mode(render_mode, RENDER_MODES)
        self.overlay = render_mode == "human" if overlay is None else check_flag(overlay,
                                                                                "overlay")
        self.env = _make_batched(1, occupancy, device, seed, compile_step, config, aids,
                                 max_episode_steps, fields)
        self.observation_space, self._action_box, self._scale = _spaces(
            self.env, check_flag(physical_actions, "physical_actions"))
        self.action_space = self._action_box
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.env.config.vehicle.dt)}
        self._window = None
        if render_mode == "human":  # pygame, or the error naming the extra
            from torchpark.media.window import Window

            self._window = Window(fps=self.metadata["render_fps"])
        self._action = TensorDict({"action": torch.zeros(1, 2, device=self.env.device)},
                                  batch_size=[1], device=self.env.device)
        self._ended = True  # no episode yet: reset() first
        self._stepped = False  # whether self._action holds the last step (not a reset)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        """A new lot and start (Gymnasium's ``reset``): ``seed`` reseeds the env's generator,
        ``options`` may set ``occupancy``. Returns the observation (23,) float32 and info."""
        super().reset(seed=seed)
        td = _reset_lots(self.env, seed, options)
        self._ended, self._stepped = False, False
        self._show()
        return self._observe(td), self._info(td)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One step at ``action`` (v, delta) in the action space (Gymnasium's ``step``):
        observation, reward, terminated, truncated, info; after an episode's end, reset
        first (``ResetNeeded``)."""
        if self._ended:  # the car would stay where it collided or parked, scored again
            raise gymnasium.error.ResetNeeded("the episode has ended (terminated or truncated) "
                                              "or not begun: call env.reset() before step()")
        self._action["action"] = _checked_actions(action, self._action_box, (2,),
                                                  self.env.device)[None] * self._scale
        nxt = self.env.step(self._action)["next"]
        terminated, truncated = bool(nxt["terminated"][0, 0]), bool(nxt["truncated"][0, 0])
        self._ended, self._stepped = terminated or truncated, True
        self._show()
        return (self._observe(nxt), float(nxt["reward"][0, 0]), terminated, truncated,
                self._info(nxt))

    def render(self) -> np.ndarray | None:
        """The lot's picture (rgb_array); None in human mode, whose window every reset and
        step draw (Gymnasium's convention), and without a render_mode."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass "
                                  "render_mode='rgb_array' or 'human' to gymnasium.make")
            return None
        if self.render_mode == "human":
            self._show()
            return None
        return self._picture()

    def close(self) -> None:
        """Close the window, if one is open."""
        if self._window is not None:
            self._window.close()
        super().close()

    def _show(self) -> None:
        """Human mode: the lot now in the window (the goal outlined over the car; with the
        brake or the docking law on, which layer drove the step; the overlay)."""
        if self._window is not None:
            self._window.show(self._picture())

    def _picture(self) -> np.ndarray:
        """The lot now, with the overlay's numbers where ``overlay`` is on."""
        return self.env.render(0, self.readout() if self.overlay else None)

    def readout(self) -> Readout:
        """The overlay's numbers now (:meth:`ParkingEnv.readout`): the step count, speed,
        the last step's steering delta (rad, the env's physical action) and outcome, the
        cost C against the success threshold and the pose error in the goal's frame."""
        return self.env.readout(0, self._action if self._stepped else None)

    def _observe(self, td: TensorDictBase) -> Any:
        """The observation Gymnasium returns, from the step's (or reset's) output."""
        return td["observation"][0].cpu().numpy()

    def _info(self, td: TensorDictBase) -> dict[str, Any]:
        info = {key: value[0] for key, value in _numpy_info(td).items()}
        return {**info, "success": bool(info["success"]), "collision": bool(info["collision"]),
                "occupancy": float(info["occupancy"])}


class ParkingVectorEnv(VectorEnv):
    """N parking lots as one native Gymnasium ``VectorEnv`` backed by one ``ParkingEnv(N)``.

    Autoreset: ``AutoresetMode.SAME_STEP``. A lot whose episode ends is redrawn in the same
    ``step``: the returned observation is the new lot's first one, the last observation of
    the ended episode is in ``info["final_obs"]`` and its info in ``info["final_info"]``
    (rows marked by ``info["_final_obs"]``), as Gymnasium's ``SyncVectorEnv`` does in that
    mode. ``info`` also holds ``success``, ``collision`` and ``occupancy`` arrays (N,).
    ``reset(options={"reset_mask": mask})`` draws new lots for the rows of the numpy bool
    array ``mask`` (N,) only, as Gymnasium's ``SyncVectorEnv`` does (the other rows'
    observations as they were; the infos' ``_`` masks mark the reset rows); ``seed`` is the
    batch's one generator's, a list of seeds is refused.
    ``render()`` returns a tuple of the first ``render_envs`` lots' pictures.
    ``max_episode_steps`` (which ``make_vec`` passes: 1,000 unless given) is the episodes'
    step limit.
    """

    metadata: dict[str, Any] = {  # noqa: RUF012 (an attribute of Gymnasium's VectorEnv)
        "render_modes": VECTOR_RENDER_MODES, "render_fps": 10,
        "autoreset_mode": AutoresetMode.SAME_STEP}
    occupancy = _batch_occupancy()

    def __init__(self, num_envs: int, render_mode: str | None = None, *,
                 occupancy: float | None = None, device: torch.device | str = "cpu",
                 seed: int | None = None, compile_step: bool = False,
                 physical_actions: bool = False, config: ParkingConfig | None = None,
                 aids: AidsConfig | None = None, render_envs: int = 16,
                 max_episode_steps: int | None = None, **fields: Any) -> None:
        self.render_mode = _check_render_mode(render_mode, VECTOR_RENDER_MODES)
        self.env = _make_batched(num_envs, occupancy, device, seed, compile_step,
                                 config, aids, max_episode_steps, fields)
        self.num_envs = num_envs
        self.render_envs = render_envs
        self.single_observation_space, self._action_box, self._scale = _spaces(
            self.env, check_flag(physical_actions, "physical_actions"))
        self.single_action_space = self._action_box
        self.observation_space = gymnasium.vector.utils.batch_space(
            self.single_observation_space, num_envs)
        self.action_space = gymnasium.vector.utils.batch_space(self.single_action_space, num_envs)
        self._td: TensorDictBase | None = None

    @property
    def render_envs(self) -> int:
        """How many lots ``render()`` pictures (the first ones): an int >= 1, at most
        ``num_envs`` (a larger one is taken as ``num_envs``)."""
        return self._render_envs

    @render_envs.setter
    def render_envs(self, value: int) -> None:
        if not is_integer(value) or value < 1:
            raise ValueError(f"render_envs must be an int >= 1, got {value!r}")
        self._render_envs = min(int(value), self.num_envs)

    def reset(self, *, seed: int | list[int] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """New lots for every env, or for those of ``options["reset_mask"]`` (Gymnasium's
        partial reset): ``seed`` one int for the whole batch (one generator). Returns the
        observations (N, 23) and info."""
        if isinstance(seed, list):
            raise ValueError("seed must be one int for the whole batch (one generator), "
                             f"got a list of {len(seed)}")
        super().reset(seed=seed)
        options, mask = _reset_mask(options, self.num_envs)
        mask = mask if self._td is not None else None  # the first reset draws every lot
        self._td = _reset_lots(self.env, seed, options, mask, self._td)
        info = self._info(self._td)
        if mask is not None:  # Gymnasium's partial reset: the reset rows' infos
            info.update({f"_{k}": mask for k in info if not k.startswith("_")})
        return self._td["observation"].cpu().numpy(), info

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                          dict[str, Any]]:
        """One step of every env at ``actions`` (N, 2), the ended ones redrawn in it
        (``AutoresetMode.SAME_STEP``: an ended env's last observation in
        ``info["final_obs"]``)."""
        if self._td is None:
            raise RuntimeError("call reset() before step()")
        self._td["action"] = _checked_actions(actions, self._action_box,
                                              (self.num_envs, 2), self.env.device) * self._scale
        out, self._td = self.env.step_and_maybe_reset(self._td)
        nxt = out["next"]
        done = nxt["done"][:, 0].cpu().numpy()
        info = self._info(self._td)
        if done.any():
            final = self._info(nxt)
            info.update(final_obs=nxt["observation"].cpu().numpy(), _final_obs=done,
                        final_info={**final, **{f"_{k}": done for k in final}},
                        _final_info=done)
        return (self._td["observation"].cpu().numpy(), nxt["reward"][:, 0].cpu().numpy(),
                nxt["terminated"][:, 0].cpu().numpy(), nxt["truncated"][:, 0].cpu().numpy(),
                info)

    def render(self) -> tuple[np.ndarray, ...] | None:
        """Pictures of the first ``render_envs`` lots (rgb_array); None without a
        render_mode."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass "
                                  "render_mode='rgb_array' to gymnasium.make_vec")
            return None
        return tuple(self.env.render(i) for i in range(self.render_envs))

    def _info(self, td: TensorDictBase) -> dict[str, Any]:
        info = _numpy_info(td)
        mask = np.ones(self.num_envs, dtype=bool)
        return {**info, **{f"_{k}": mask for k in info}}


def register() -> None:
    """Register ``torchpark/Parking-v0`` and the goal-conditioned ``torchpark/ParkingGoal-v0``
    (:mod:`torchpark.goal_env`), done on ``import torchpark``; idempotent. Their
    ``spec.max_episode_steps`` is the paper's 1,000 steps (``ParkingConfig.max_steps``)."""
    steps = ParkingConfig().max_steps
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="torchpark.gym_env:ParkingGymEnv",
                           vector_entry_point="torchpark.gym_env:ParkingVectorEnv",
                           max_episode_steps=steps)
    if GOAL_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=GOAL_ENV_ID, entry_point="torchpark.goal_env:ParkingGoalEnv",
                           max_episode_steps=steps)
