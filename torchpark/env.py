"""``ParkingEnv``: N parking lots as one batch-locked TorchRL environment.

The class is plumbing: specs, seeding, action checks, and reset muxing. The physics lives in
``simulation`` (composed from ``vehicle``, ``geometry``, ``lidar``, ``reward``) and the lot in
``lot``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Composite, Unbounded
from torchrl.envs import EnvBase

from torchpark.config import (
    ParkingConfig,
    check_flag,
    check_occupancy,
    is_integer,
    is_number,
)
from torchpark.geometry import BoxFrame, box_frame
from torchpark.lidar import line_rotation
from torchpark.lot import build_layout, draw_goals_and_cars, draw_starts
from torchpark.rendering import LotRenderer, frame_grid
from torchpark.simulation import (
    ParkingState,
    World,
    merge_steps,
    parking_step,
    reset_rows,
    steer_angles,
)


class ParkingEnv(EnvBase):
    """The paper's parking task for ``num_envs`` lots at once, every tensor on ``device``.

    Args:
        num_envs: number of lots (the batch size), >= 1.
        device: torch device of every tensor.
        seed: seed of the env's own ``torch.Generator``; None draws one from torch's global RNG.
        config: a :class:`ParkingConfig`; the paper's values by default.
        compile_step: run the step and the reset's tensor work through
            ``torch.compile(fullgraph=True)``. Worth it from a few hundred envs on (several times
            faster on CPU); the first step then takes tens of seconds to compile.
        compile_kwargs: passed to ``torch.compile``.
        validate_actions: raise on non-finite actions (the state is then left as it was). The
            test runs inside the step; reading its bool is free on CPU, a synchronisation on
            CUDA: turn it off for GPU throughput.

    Actions (N, 2) = (v m/s, delta rad) are clamped to [-max_speed, max_speed] and
    [-max_steer, max_steer] (documented behaviour); a non-finite action raises ValueError.
    float32 actions are taken as they are and float64 ones (what numpy gives) rounded to
    float32, the env's precision; half precision (float16, bfloat16: millimetres off after
    100 steps, where success needs ~1 mm), integer and bool actions raise ValueError. Actions
    are detached: no autograd graph enters the state. ``step`` before the first ``reset``
    raises RuntimeError (the state holds no lot yet).
    Outputs per step: observation (N, 7 + n_rays) float32; reward, done, terminated, truncated,
    success, collision (N, 1); braked (N, 1) bool, whether the emergency brake stopped the last
    step of dt; occupancy (N, 1) float32, the occupancy the current lot was drawn with.
    Setting :attr:`occupancy` applies to lots drawn at later resets. With
    ``config.action_repeat = k`` each step holds the action for up to k steps of ``dt``
    (stopping at the one that ends the episode) and returns the sum of their rewards.
    """

    batch_locked = True

    def __init__(
        self,
        num_envs: int,
        *,
        device: torch.device | str = "cpu",
        seed: int | None = None,
        config: ParkingConfig | None = None,
        compile_step: bool = False,
        compile_kwargs: dict | None = None,
        validate_actions: bool = True,
    ) -> None:
        if not is_integer(num_envs) or num_envs < 1:
            raise ValueError(f"num_envs must be an int >= 1, got {num_envs!r}")
        num_envs = int(num_envs)
        compile_step = check_flag(compile_step, "compile_step")
        validate_actions = check_flag(validate_actions, "validate_actions")
        if compile_kwargs is not None and not isinstance(compile_kwargs, dict):
            raise TypeError(f"compile_kwargs must be a dict or None, got {compile_kwargs!r}")
        if config is not None and not isinstance(config, ParkingConfig):
            raise TypeError(f"config must be a ParkingConfig, got {type(config).__name__}")
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.num_envs = num_envs
        self.config = config if config is not None else ParkingConfig()
        self.validate_actions = validate_actions
        self._occupancy = self.config.occupancy
        cfg = self.config
        self.layout = build_layout(cfg.lot, cfg.vehicle, self.device)
        # World holds this tensor; the success_threshold setter and SuccessCurriculum change it
        # in place, and a compiled step reads it at run time.
        self._success_threshold = torch.tensor(cfg.reward.success_threshold,
                                               dtype=torch.float32, device=self.device)
        self._world = World(
            obstacles=BoxFrame(*(t.contiguous() for t in box_frame(self.layout.obstacles))),
            rotation=line_rotation(cfg.lidar.n_rays, self.device),
            goal_poses=self.layout.goal_poses,
            slots_and_walls=self.layout.slots_and_walls,
            extent=torch.tensor([self.layout.width, self.layout.height], device=self.device),
            success_threshold=self._success_threshold,
            steer_angles=steer_angles(cfg, self.device),
        )
        step_fn = partial(parking_step, world=self._world, cfg=cfg)
        reset_fn = partial(reset_rows, world=self._world, cfg=cfg)
        merge_fn = merge_steps
        if compile_step:
            step_fn, reset_fn, merge_fn = (
                torch.compile(f, fullgraph=True, **(compile_kwargs or {}))
                for f in (step_fn, reset_fn, merge_fn)
            )
        self._step_fn, self._reset_fn, self._merge_fn = step_fn, reset_fn, merge_fn
        self._make_specs()
        self._generator = torch.Generator(device=self.device)
        self._set_seed(seed)
        self._init_state()
        self._renderer: LotRenderer | None = None

    # ------------------------------------------------------------------ configuration
    @property
    def occupancy(self) -> float:
        """Fraction in [0, 1] of the non-goal slots that hold a parked car in lots drawn from
        now on (exactly round_half_up(occupancy * (S - 1)) cars)."""
        return self._occupancy

    @occupancy.setter
    def occupancy(self, value: float) -> None:
        self._occupancy = check_occupancy(value, "occupancy")

    @property
    def success_threshold(self) -> float:
        """The success test's threshold on C (``config.reward.success_threshold`` at first).
        Setting it applies from the next step; ``SuccessCurriculum`` lowers it in training."""
        return float(self._success_threshold)

    @success_threshold.setter
    def success_threshold(self, value: float) -> None:
        if not is_number(value) or not math.isfinite(value) or value <= 0:
            raise ValueError(f"success_threshold must be a finite float > 0, got {value!r}")
        self._success_threshold.fill_(float(value))

    @property
    def obs_dim(self) -> int:
        return 7 + self.config.lidar.n_rays

    def _make_specs(self) -> None:
        n, dev, veh = self.num_envs, self.device, self.config.vehicle

        def flag() -> Binary:
            return Binary(n=1, shape=(n, 1), dtype=torch.bool, device=dev)

        self.observation_spec = Composite(
            observation=Unbounded(shape=(n, self.obs_dim), dtype=torch.float32, device=dev),
            success=flag(),
            collision=flag(),
            braked=flag(),
            occupancy=Bounded(low=0.0, high=1.0, shape=(n, 1), dtype=torch.float32, device=dev),
            shape=(n,),
            device=dev,
        )
        self.action_spec = Bounded(
            low=torch.tensor([-veh.max_speed, -veh.max_steer], device=dev).expand(n, 2),
            high=torch.tensor([veh.max_speed, veh.max_steer], device=dev).expand(n, 2),
            shape=(n, 2), dtype=torch.float32, device=dev,
        )
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32, device=dev)
        self.full_done_spec = Composite(
            done=flag(), terminated=flag(), truncated=flag(), shape=(n,), device=dev
        )

    # ------------------------------------------------------------------ seeding and state
    def _set_seed(self, seed: int | None) -> None:
        if seed is not None and (not is_integer(seed) or not 0 <= seed < 2**63):
            raise ValueError(f"seed must be an int in [0, 2**63) or None, got {seed!r}")
        if seed is None:
            seed = int(torch.randint(0, 2**62, (), dtype=torch.int64))
        self._generator.manual_seed(int(seed))

    def _init_state(self) -> None:
        n, dev = self.num_envs, self.device
        m = self._world.obstacles.cx.shape[0]
        self._state = ParkingState(
            pose=torch.zeros(n, 3, device=dev),
            speed=torch.zeros(n, device=dev),
            goal_slot=torch.zeros(n, dtype=torch.int64, device=dev),
            goal=torch.zeros(n, 3, device=dev),
            present=torch.zeros(n, m, device=dev),
            steps=torch.zeros(n, dtype=torch.int64, device=dev),
            occupancy=torch.zeros(n, device=dev),
            braked=torch.zeros(n, dtype=torch.bool, device=dev),
            brakes=torch.zeros(n, dtype=torch.int64, device=dev),
            docking=torch.zeros(n, dtype=torch.bool, device=dev),
            reversing=torch.zeros(n, dtype=torch.bool, device=dev),
        )
        self._observation = torch.zeros(n, self.obs_dim, device=dev)
        self._started = False  # no lot drawn yet: reset() first

    def randomize_step_counts(self) -> None:
        """Set every env's step count to a uniform draw in [0, max_steps), from the env's
        generator, so the current episodes end at spread-out times.

        For training: after a full reset all N episodes would otherwise time out together,
        and a batch of a few steps from each env would be one time slice of synchronised
        episodes (e.g. only their first steps), again at every timeout.
        """
        steps = torch.randint(self.config.max_steps, (self.num_envs,),
                              generator=self._generator, device=self.device)
        self._state = self._state._replace(steps=steps)

    @property
    def state(self) -> ParkingState:
        """The current per-env state (read-only view for analysis and tests)."""
        return self._state

    # ------------------------------------------------------------------ pictures
    def render(self, index: int = 0) -> np.ndarray:
        """Picture of env ``index``'s lot now, (H, W, 3) uint8 (see :mod:`torchpark.rendering`)."""
        if not is_integer(index) \
                or not 0 <= index < self.num_envs:
            raise IndexError(f"index must be an int in [0, {self.num_envs - 1}], got {index!r}")
        return self.render_grid([int(index)])

    def render_grid(self, indices: Sequence[int] | None = None, columns: int | None = None
                    ) -> np.ndarray:
        """Pictures of several envs' lots (default: all) tiled row by row into one image."""
        if not self._started:
            raise RuntimeError("ParkingEnv.render before reset: call env.reset() first")
        if indices is not None and not all(is_integer(i) for i in indices):
            raise IndexError(f"indices must be ints in [0, {self.num_envs - 1}], got "
                             f"{list(indices)}")
        indices = list(range(self.num_envs)) if indices is None else [int(i) for i in indices]
        bad = [i for i in indices if not 0 <= i < self.num_envs]
        if bad or not indices:
            raise IndexError(f"indices must be non-empty ints in [0, {self.num_envs - 1}], "
                             f"got {bad or indices}")
        if self._renderer is None:
            self._renderer = LotRenderer(self.layout, self.config)
        rows = torch.tensor(indices, device=self.device)
        s = self.layout.num_slots
        parked = (self._state.present[rows, :s] > 0.5).cpu().numpy()
        goal = self._state.goal_slot[rows].cpu().numpy()
        pose = self._state.pose[rows].cpu().numpy()
        lidar = self._observation[rows, 7:].cpu().numpy()
        frames = [self._renderer.frame(*row) for row in zip(parked, goal, pose, lidar, strict=True)]
        return frames[0] if len(frames) == 1 else frame_grid(frames, columns)

    # ------------------------------------------------------------------ EnvBase hooks
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        n, dev = self.num_envs, self.device
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(n)
        else:
            mask = torch.ones(n, dtype=torch.bool, device=dev)
        # Every row draws a new lot; the masked rows take it (torch.where, no sync), the
        # others keep their state bit for bit.
        goal, occupied = draw_goals_and_cars(
            n, self.layout.num_slots, self._occupancy, self._generator, dev
        )
        start = draw_starts(self.layout.goal_poses[goal], self.layout, self.config.lot,
                            self._generator)
        occupancy = torch.full((n,), self._occupancy, device=dev)
        if not self._started:  # the first reset draws every row, whatever the mask
            mask = torch.ones_like(mask)
        self._state, self._observation = self._reset_fn(
            self._state, self._observation, mask, goal, occupied, occupancy, start
        )
        self._started = True
        no = torch.zeros(n, 1, dtype=torch.bool, device=dev)
        return TensorDict(
            {
                "observation": self._observation.clone(),  # the caller's, not our buffer
                "success": no, "collision": no.clone(), "braked": no.clone(),
                "occupancy": self._state.occupancy[:, None],
                "done": no.clone(), "terminated": no.clone(), "truncated": no.clone(),
            },
            batch_size=self.batch_size, device=dev,
        )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        if not self._started:
            raise RuntimeError("ParkingEnv.step before reset: call env.reset() first")
        action = tensordict.get("action")
        if action.shape != (self.num_envs, 2):
            raise ValueError(
                f"action must have shape ({self.num_envs}, 2) = (num_envs, [v, delta]), "
                f"got {tuple(action.shape)}"
            )
        if action.device != self.device:
            raise ValueError(f"action must be on the env's device {self.device}, got "
                             f"{action.device}")
        if action.dtype not in (torch.float32, torch.float64):
            raise ValueError(f"action must be float32 (or float64, rounded to float32), got "
                             f"{action.dtype}")
        action = action.detach().to(torch.float32)
        state, out, finite = self._step_fn(self._state, action)
        if self.validate_actions and not bool(finite):  # before the state is kept
            raise ValueError("action must be finite (no NaN or inf); got a non-finite value")
        for _ in range(self.config.action_repeat - 1):  # the held action's further dt steps
            state, out = self._merge_fn(state, out, *self._step_fn(state, action)[:2])
        self._state, self._observation = state, out.observation
        return TensorDict(
            {**out._asdict(), "observation": out.observation.clone(),
             "occupancy": self._state.occupancy[:, None],
             "braked": self._state.braked[:, None]},
            batch_size=self.batch_size, device=self.device,
        )
