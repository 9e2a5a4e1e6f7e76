"""The batched parking step and reset as pure tensor functions (no Python branching on tensor
values, no host sync, static shapes), composed from vehicle, geometry, lidar and reward.

``ParkingEnv`` binds the constants with ``functools.partial`` and may ``torch.compile`` both
functions with ``fullgraph=True``.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.config import ParkingConfig
from torchpark.docking import docking_action, docking_phase, goal_frame_error
from torchpark.geometry import BoxFrame, frames_separation
from torchpark.lidar import lidar_scan
from torchpark.lot import StartDraw, choose_start
from torchpark.reward import is_success, parking_cost, parking_reward
from torchpark.vehicle import bicycle_step, clamp_action, vehicle_frame

_ABSENT_GAP = 1e4  # metres


class World(NamedTuple):
    """Constants shared by every env. obstacles: frame with fields (M,) = S parked-car boxes
    then 4 walls; rotation: LIDAR line rotation (2, 2 * lines); goal_poses: (S, 3) rear-axle
    goal pose of each slot; slots_and_walls: frame (S + 4,) that a start pose must not touch;
    extent: (2,) the lot's width and height, m; success_threshold: () the success test's
    threshold on C, a tensor so that changing it in place needs no recompilation;
    steer_angles: (K,) rad, the steering angles the brake tries (``ParkingConfig.steer_clear``
    = K, evenly spread over the vehicle's range; empty when 0)."""

    obstacles: BoxFrame
    rotation: Tensor
    goal_poses: Tensor
    slots_and_walls: BoxFrame
    extent: Tensor
    success_threshold: Tensor
    steer_angles: Tensor


def steer_angles(cfg: ParkingConfig, device: torch.device | str | None = None) -> Tensor:
    """The brake's (K,) steering angles, rad: ``cfg.steer_clear`` evenly spread over
    [-max_steer, max_steer]."""
    return torch.linspace(-cfg.vehicle.max_steer, cfg.vehicle.max_steer, cfg.steer_clear,
                          device=device)


class ParkingState(NamedTuple):
    """Per-env state.

    pose (N, 3) rear axle (x m, y m, psi rad); speed (N,) m/s; goal_slot (N,) int64; goal
    (N, 3) its goal pose; present (N, M) float32, 1 where the obstacle exists (a parked car in
    that slot; walls always), else 0; steps (N,) int64 steps taken this episode; occupancy (N,)
    float32 the lot was drawn with; braked (N,) bool, whether the emergency brake stopped the
    last step, brakes (N,) int64 how many steps it stopped or steered (``steer_clear``) this
    episode; docking (N,) bool, whether the docking layer (``ParkingConfig.docking``) drives
    this episode, reversing (N,) bool, whether it is reversing. ``present`` is float, not
    bool: compiled kernels loaded bool masks with branches that a random occupancy pattern
    mispredicted (45% slower).
    """

    pose: Tensor
    speed: Tensor
    goal_slot: Tensor
    goal: Tensor
    present: Tensor
    steps: Tensor
    occupancy: Tensor
    braked: Tensor
    brakes: Tensor
    docking: Tensor
    reversing: Tensor


class StepResult(NamedTuple):
    """What one step emits; all (N, 1) except observation (N, 7 + n_rays) float32."""

    observation: Tensor
    reward: Tensor
    terminated: Tensor
    truncated: Tensor
    done: Tensor
    success: Tensor
    collision: Tensor


def touches_obstacle(ego: BoxFrame, world: World, present: Tensor) -> Tensor:
    """Whether vehicle boxes (frame with fields [...]) touch a present obstacle: bool [...].

    present: float [..., M] broadcastable, 1 where the obstacle exists.
    """
    gap = frames_separation(BoxFrame(*(t[..., None] for t in ego)), world.obstacles)
    # An absent obstacle's gap is raised by _ABSENT_GAP, far more than any overlap depth.
    return (gap + (1.0 - present) * _ABSENT_GAP).amin(-1) <= 0.0


def observe(state: ParkingState, world: World, cfg: ParkingConfig) -> tuple[Tensor, Tensor]:
    """Observation (N, 7 + n_rays) and parking cost C (N,) of a state.

    Observation: [dx, dy, cos psi, sin psi, v, cos alpha, sin alpha, lidar / max_range], with
    dx, dy = goal - rear axle (world frame, m) and alpha the goal heading.
    """
    ego = vehicle_frame(state.pose, cfg.vehicle)
    lidar = lidar_scan(ego.cx, ego.cy, ego.cos, ego.sin, world.rotation, world.obstacles,
                       state.present, cfg.lidar.n_rays, cfg.lidar.max_range)
    dx = state.goal[:, 0] - state.pose[:, 0]
    dy = state.goal[:, 1] - state.pose[:, 1]
    alpha = state.goal[:, 2]
    nav = torch.stack(
        (dx, dy, ego.cos, ego.sin, state.speed, torch.cos(alpha), torch.sin(alpha)), dim=-1
    )
    observation = torch.cat((nav, lidar * (1.0 / cfg.lidar.max_range)), dim=-1)
    cost = parking_cost(dx, dy, state.pose[:, 2], alpha, state.speed, cfg.reward)
    return observation, cost


def _mux_rows(mask: Tensor, new: tuple, old: tuple) -> tuple:
    """Field by field, ``new`` where ``mask`` (N,) is set, else ``old``: NamedTuples of
    [N, ...] tensors."""
    return type(old)(*(
        torch.where(mask.view(-1, *([1] * (a.dim() - 1))), a, b)
        for a, b in zip(new, old, strict=True)
    ))


def parking_step(state: ParkingState, action: Tensor, world: World, cfg: ParkingConfig
                 ) -> tuple[ParkingState, StepResult, Tensor]:
    """Advance every env by one step of (v, delta) actions (N, 2), clamped to the limits.

    Also returns whether every action was finite, () bool: computed inside the (compiled)
    step, where it costs nothing, so the caller can reject the step before keeping its state.
    """
    v, delta = clamp_action(action, cfg.vehicle)
    docking, reversing = state.docking, state.reversing
    if cfg.docking is not None:
        # Once in the funnel, the docking law drives until the episode ends.
        error = goal_frame_error(state.pose, state.goal)
        docking, reversing = docking_phase(error, docking, reversing, state.braked, cfg.docking)
        law_v, law_delta = docking_action(error, reversing, cfg.docking, cfg.vehicle)
        v = torch.where(docking, law_v, v)
        delta = torch.where(docking, law_delta, delta)
    pose = bicycle_step(state.pose, v, delta, cfg.vehicle)
    collision = touches_obstacle(vehicle_frame(pose, cfg.vehicle), world, state.present)
    braked = intervened = torch.zeros_like(collision)
    if cfg.emergency_brake:
        intervened = collision
        if cfg.steer_clear:
            # The same speed at other steering angles: the clear one nearest the commanded.
            n, k = v.shape[0], cfg.steer_clear
            spread = world.steer_angles
            tries = bicycle_step(state.pose[:, None, :].expand(n, k, 3),
                                 v[:, None].expand(n, k), spread.expand(n, k),
                                 cfg.vehicle)  # (N, K, 3)
            clear = ~touches_obstacle(vehicle_frame(tries, cfg.vehicle), world,
                                      state.present[:, None, :])
            gap = (spread - delta[:, None]).abs() + torch.where(clear, 0.0, 1e3)
            steered = collision & clear.any(-1)
            chosen = torch.take_along_dim(tries, gap.argmin(-1)[:, None, None], dim=1)[:, 0]
            pose = torch.where(steered[:, None], chosen, pose)
            collision = collision & ~steered
        # Keep the old pose where the new one would still collide. The old pose is
        # collision-free (a start is, and so is every pose a braked step keeps), so nothing
        # collides.
        braked, collision = collision, braked
        pose = torch.where(braked[:, None], state.pose, pose)
        v = torch.where(braked, 0.0, v)
    state = state._replace(pose=pose, speed=v, steps=state.steps + 1, braked=braked,
                           brakes=state.brakes + intervened.long(), docking=docking,
                           reversing=reversing)
    observation, cost = observe(state, world, cfg)
    success = is_success(cost, world.success_threshold)
    reward = parking_reward(cost, collision, success, braked, cfg.reward)
    terminated = collision | success
    truncated = (state.steps >= cfg.max_steps) & ~terminated
    column = (reward, terminated, truncated, terminated | truncated, success, collision)
    return state, StepResult(observation, *(t[:, None] for t in column)), action.isfinite().all()


def merge_steps(state: ParkingState, out: StepResult, new_state: ParkingState,
                new_out: StepResult) -> tuple[ParkingState, StepResult]:
    """Append one more physics step (``new_*``, taken from ``state``) to a held action's
    steps so far: rows already done keep their state and outputs; the others take the new
    ones, with the rewards summed."""
    live = ~out.done[:, 0]
    merged = _mux_rows(live, new_out, out)
    return _mux_rows(live, new_state, state), merged._replace(
        reward=out.reward + torch.where(live[:, None], new_out.reward, 0.0))


def near_starts_free(near: Tensor, goal: Tensor, present: Tensor, world: World,
                     cfg: ParkingConfig) -> Tensor:
    """Whether near-goal start poses (N, J, 3) are usable, bool (N, J): rear axle inside the
    lot, vehicle box touching no present obstacle (``present`` (N, M)), success test not met
    at rest against ``goal`` (N, 3)."""
    free = ~touches_obstacle(vehicle_frame(near, cfg.vehicle), world, present[:, None, :])
    inside = ((near[..., :2] > 0.0) & (near[..., :2] < world.extent)).all(-1)
    g = goal[:, None, :]
    cost = parking_cost(g[..., 0] - near[..., 0], g[..., 1] - near[..., 1], near[..., 2],
                        g[..., 2], torch.zeros_like(near[..., 0]), cfg.reward)
    return free & inside & ~is_success(cost, world.success_threshold)


def reset_rows(state: ParkingState, observation: Tensor, mask: Tensor, goal_slot: Tensor,
               occupied: Tensor, occupancy: Tensor, start: StartDraw, world: World,
               cfg: ParkingConfig) -> tuple[ParkingState, Tensor]:
    """New lots for the rows where ``mask`` (N,) is set; the other rows are returned untouched.

    goal_slot (N,) int64, occupied (N, S) bool, occupancy (N,) float32: the drawn lot;
    start: the start poses' random draws (``lot.draw_starts``).
    Every row is computed and muxed with ``torch.where``: static shapes and no host sync, so
    a partial reset compiles into the same graph as a full one.
    """
    walls = torch.ones(occupied.shape[0], world.obstacles.cx.shape[0] - occupied.shape[1],
                       device=occupied.device)
    present = torch.cat((occupied.to(walls.dtype), walls), dim=-1)
    goal = world.goal_poses[goal_slot]
    near_free = near_starts_free(start.near, goal, present, world, cfg)
    fresh = ParkingState(
        pose=choose_start(start, world.slots_and_walls, near_free, cfg.vehicle),
        speed=torch.zeros_like(state.speed),
        goal_slot=goal_slot,
        goal=goal,
        present=present,
        steps=torch.zeros_like(state.steps),
        occupancy=occupancy,
        braked=torch.zeros_like(state.braked),
        brakes=torch.zeros_like(state.brakes),
        docking=torch.zeros_like(state.docking),
        reversing=torch.zeros_like(state.reversing),
    )
    state = _mux_rows(mask, fresh, state)
    new_observation, _ = observe(state, world, cfg)
    return state, torch.where(mask[:, None], new_observation, observation)
