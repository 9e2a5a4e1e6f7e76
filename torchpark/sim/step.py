"""The paper's batched step and reset as pure tensor functions (no Python branching on tensor
values, no host sync, static shapes), composed from vehicle, geometry, lidar and reward.

``ParkingEnv`` binds the constants with ``functools.partial`` and may ``torch.compile`` them
with ``fullgraph=True``. The agent-side aids (:mod:`torchpark.aids`) compose these same
pieces (:func:`move`, :func:`commit`, :func:`new_lots`, :func:`place`); nothing here knows
about them.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.config import ParkingConfig
from torchpark.sim.episodes import LotDraw, choose_start
from torchpark.sim.observation import observe
from torchpark.sim.reward import is_success, parking_reward
from torchpark.sim.vehicle import bicycle_step, clamp_action, vehicle_obb
from torchpark.sim.world import World, touches_obstacle


class ParkingState(NamedTuple):
    """Per-env state of the paper's task.

    pose (N, 3) rear axle (x m, y m, psi rad); speed (N,) m/s; goal_slot (N,) int64; goal
    (N, 3) its goal pose; present (N, M) float32, 1 where the obstacle exists (a parked car in
    that slot; walls always), else 0; steps (N,) int64 steps of dt taken this episode;
    occupancy (N,) float32 the lot was drawn with. ``present`` is float, not bool: compiled
    kernels loaded bool masks with branches that a random occupancy pattern mispredicted
    (45% slower).
    """

    pose: Tensor
    speed: Tensor
    goal_slot: Tensor
    goal: Tensor
    present: Tensor
    steps: Tensor
    occupancy: Tensor

    @classmethod
    def zeros(cls, num_envs: int, num_obstacles: int, device: torch.device | str
              ) -> ParkingState:
        """A state of ``num_envs`` rows holding no lot (every field zero)."""
        n = num_envs
        return cls(
            pose=torch.zeros(n, 3, device=device),
            speed=torch.zeros(n, device=device),
            goal_slot=torch.zeros(n, dtype=torch.int64, device=device),
            goal=torch.zeros(n, 3, device=device),
            present=torch.zeros(n, num_obstacles, device=device),
            steps=torch.zeros(n, dtype=torch.int64, device=device),
            occupancy=torch.zeros(n, device=device),
        )


class StepResult(NamedTuple):
    """What one step emits; all (N, 1) except observation (N, NAV_DIM + n_rays) float32.
    cost: the paper's C after the step (float32), what the success test compares."""

    observation: Tensor
    reward: Tensor
    terminated: Tensor
    truncated: Tensor
    done: Tensor
    success: Tensor
    collision: Tensor
    cost: Tensor


def mux_rows(mask: Tensor, new: tuple, old: tuple) -> tuple:
    """Field by field, ``new`` where ``mask`` (N,) is set, else ``old``: NamedTuples (nested
    ones too) of [N, ...] tensors."""
    return type(old)(*(
        mux_rows(mask, a, b) if isinstance(b, tuple)
        else torch.where(mask.view(-1, *([1] * (a.dim() - 1))), a, b)
        for a, b in zip(new, old, strict=True)
    ))


def move(pose: Tensor, v: Tensor, delta: Tensor, present: Tensor, world: World,
         cfg: ParkingConfig) -> tuple[Tensor, Tensor]:
    """One bicycle step of dt from rear-axle poses [..., 3] at (v m/s, delta rad) [...], and
    whether the vehicle box then touches a present obstacle (``present`` [..., M]): the new
    poses [..., 3] and bool [...]."""
    pose = bicycle_step(pose, v, delta, cfg.vehicle)
    return pose, touches_obstacle(vehicle_obb(pose, cfg.vehicle), world, present)


def commit(state: ParkingState, pose: Tensor, speed: Tensor, collision: Tensor, world: World,
           cfg: ParkingConfig) -> tuple[ParkingState, StepResult]:
    """The state after a step of dt that ends at ``pose`` (N, 3) with ``speed`` (N,), having
    touched an obstacle where ``collision`` (N,), and what the step emits: observation,
    Table-1 reward, and the episode's end (success or collision terminates, max_steps
    truncates)."""
    state = state._replace(pose=pose, speed=speed, steps=state.steps + 1)
    observation, cost = observe(state, world, cfg)
    success = is_success(cost, world.success_threshold)
    reward = parking_reward(cost, collision, success, cfg.reward)
    terminated = collision | success
    truncated = (state.steps >= cfg.max_steps) & ~terminated
    column = (reward, terminated, truncated, terminated | truncated, success, collision, cost)
    return state, StepResult(observation, *(t[:, None] for t in column))


def parking_step(state: ParkingState, action: Tensor, world: World, cfg: ParkingConfig
                 ) -> tuple[ParkingState, StepResult, Tensor]:
    """The paper's step for every env: clamp the (v, delta) actions (N, 2) to the limits,
    one bicycle step of dt, the SAT collision test, then observe, reward, done.

    Also returns whether every action was finite, () bool: computed inside the (compiled)
    step, where it costs nothing, so the caller can reject the step before keeping its state.
    """
    v, delta = clamp_action(action, cfg.vehicle)
    pose, collision = move(state.pose, v, delta, state.present, world, cfg)
    state, result = commit(state, pose, v, collision, world, cfg)
    return state, result, action.isfinite().all()


def new_lots(lots: LotDraw, world: World, cfg: ParkingConfig) -> ParkingState:
    """The states (N rows) of freshly drawn lots: at rest at their start poses, no step
    taken."""
    occupied = lots.occupied
    walls = torch.ones(occupied.shape[0], world.obstacles.cx.shape[0] - occupied.shape[1],
                       device=occupied.device)
    return ParkingState(
        pose=choose_start(lots.start, world.slots_and_walls, cfg.vehicle),
        speed=torch.zeros(occupied.shape[0], device=occupied.device),
        goal_slot=lots.goal_slot,
        goal=world.goal_poses[lots.goal_slot],
        present=torch.cat((occupied.to(walls.dtype), walls), dim=-1),
        steps=torch.zeros(occupied.shape[0], dtype=torch.int64, device=occupied.device),
        occupancy=lots.occupancy,
    )


def place(state: ParkingState, observation: Tensor, cost: Tensor, mask: Tensor,
          fresh: ParkingState, world: World, cfg: ParkingConfig
          ) -> tuple[ParkingState, Tensor, Tensor]:
    """``fresh`` where ``mask`` (N,) is set, ``state`` elsewhere, with the observation (N, D)
    and cost C (N,) of the rows taken from ``fresh``; the other rows' state, observation and
    cost are returned untouched, bit for bit. Every row is computed and muxed with
    ``torch.where``: static shapes and no host sync."""
    state = mux_rows(mask, fresh, state)
    new_observation, new_cost = observe(state, world, cfg)
    return (state, torch.where(mask[:, None], new_observation, observation),
            torch.where(mask, new_cost, cost))


def reset_rows(state: ParkingState, observation: Tensor, cost: Tensor, mask: Tensor,
               lots: LotDraw, world: World, cfg: ParkingConfig
               ) -> tuple[ParkingState, Tensor, Tensor]:
    """The paper's reset: the drawn ``lots`` for the rows where ``mask`` (N,) is set."""
    return place(state, observation, cost, mask, new_lots(lots, world, cfg), world, cfg)
