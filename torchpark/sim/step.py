"""The paper's batched step and reset as pure tensor functions (no Python branching on tensor
values, no host sync, static shapes), composed from vehicle, geometry, lidar and reward.

The step works on all N rows; :func:`new_episodes` makes B new episodes, which
``ParkingEnv`` draws N at a time and writes into the rows it resets in place
(:func:`put_rows_`), so a reset costs what it resets. ``ParkingEnv`` binds the constants
with ``functools.partial`` and may ``torch.compile`` them with ``fullgraph=True``. The
agent-side aids (:mod:`torchpark.aids`) compose these same pieces (:func:`move`,
:func:`commit`, :func:`new_lots`); nothing here knows about them.
"""

from __future__ import annotations

from typing import TypeVar, cast

import torch
from torch import Tensor

from torchpark.config import ParkingConfig
from torchpark.sim.episodes import LotDraw, choose_start, occupied_slots
from torchpark.sim.observation import observe
from torchpark.sim.records import replace
from torchpark.sim.reward import is_success, parking_reward
from torchpark.sim.state import ParkingState, StepResult
from torchpark.sim.vehicle import bicycle_step, clamp_action, motion_poses, vehicle_obb
from torchpark.sim.world import World, touches_obstacle

# Tuples and NamedTuples (nested ones too) of [N, ...] tensors.
RowsT = TypeVar("RowsT", bound=tuple)


def mux_rows(mask: Tensor, new: RowsT, old: RowsT) -> RowsT:
    """Field by field, ``new`` where ``mask`` (N,) is set, else ``old``: tuples and
    NamedTuples (nested ones too) of [N, ...] tensors."""
    muxed = (mux_rows(mask, a, b) if isinstance(b, tuple)
             else torch.where(mask.view(-1, *([1] * (a.dim() - 1))), a, b)
             for a, b in zip(new, old, strict=True))
    return cast(RowsT, type(old)(*muxed) if hasattr(old, "_fields") else tuple(muxed))


def move(pose: Tensor, v: Tensor, delta: Tensor, present: Tensor, world: World,
         cfg: ParkingConfig) -> tuple[Tensor, Tensor]:
    """One bicycle step of dt from rear-axle poses [..., 3] at (v m/s, delta rad) [...], and
    whether the vehicle box touches a present obstacle (``present`` [..., M]): at the end
    pose (the paper's test), or with ``cfg.collision_substeps`` = K > 1 at any of K poses
    along the step's motion (:func:`~torchpark.sim.vehicle.motion_poses`). Returns the new
    poses [..., 3] and bool [...]."""
    end = bicycle_step(pose, v, delta, cfg.vehicle)
    substeps = cfg.collision_substeps
    if substeps == 1:
        return end, touches_obstacle(vehicle_obb(end, cfg.vehicle), world, present)
    poses = motion_poses(pose, end, v, delta, substeps, cfg.vehicle)
    hits = touches_obstacle(vehicle_obb(poses, cfg.vehicle), world, present[..., None, :])
    return end, hits.any(dim=-1)


def commit(state: ParkingState, pose: Tensor, speed: Tensor, collision: Tensor, world: World,
           cfg: ParkingConfig, scan: bool = True) -> tuple[ParkingState, StepResult]:
    """The state after a step of dt that ends at ``pose`` (N, 3) with ``speed`` (N,), having
    touched an obstacle where ``collision`` (N,), and what the step emits: observation
    (its LIDAR part 0 with ``scan=False``, :func:`observe`), Table-1 reward, and the
    episode's end (success or collision terminates, max_steps truncates)."""
    state = replace(state, pose=pose, speed=speed, steps=state.steps + 1)
    observation, cost = observe(state, world, cfg, scan)
    success = is_success(cost, world.success_threshold)
    reward = parking_reward(cost, collision, success, cfg.reward)
    terminated = collision | success
    truncated = (state.steps >= cfg.max_steps) & ~terminated
    column = (reward, terminated, truncated, terminated | truncated, success, collision, cost)
    return state, StepResult(observation, *(t[:, None] for t in column))


def parking_step(state: ParkingState, action: Tensor, world: World, cfg: ParkingConfig,
                 scan: bool = True) -> tuple[ParkingState, StepResult, Tensor]:
    """The paper's step for every env: clamp the (v, delta) actions (N, 2) to the limits,
    one bicycle step of dt, the SAT collision test, then observe, reward, done.

    Also returns whether every action was finite, () bool: computed inside the (compiled)
    step, where it costs nothing, so the caller can reject the step before keeping its state.
    """
    v, delta = clamp_action(action, cfg.vehicle)
    pose, collision = move(state.pose, v, delta, state.present, world, cfg)
    state, result = commit(state, pose, v, collision, world, cfg, scan)
    return state, result, action.isfinite().all()


def new_lots(lots: LotDraw, world: World, cfg: ParkingConfig) -> ParkingState:
    """The states (B rows) of freshly drawn lots: at rest at their start poses, no step
    taken."""
    occupied = occupied_slots(lots.goal_slot, lots.keys, lots.parked)
    b, device = occupied.shape[0], occupied.device
    walls = torch.ones(b, world.obstacles.cx.shape[0] - occupied.shape[1], device=device)
    return ParkingState(
        pose=choose_start(lots.start, world.extent, world.start_pool, world.slots_and_walls,
                          cfg.vehicle),
        speed=torch.zeros(b, device=device),
        goal_slot=lots.goal_slot,
        goal=world.goal_poses[lots.goal_slot],
        present=torch.cat((occupied.to(walls.dtype), walls), dim=-1),
        steps=torch.zeros(b, dtype=torch.int64, device=device),
        occupancy=lots.occupancy,
    )


def take_rows(rows: RowsT, index: Tensor | slice) -> RowsT:
    """Field by field, the rows ``index`` ((B,) int64, or a slice: views) of tuples and
    NamedTuples (nested ones too) of [N, ...] tensors: [B, ...]."""
    taken = (take_rows(t, index) if isinstance(t, tuple) else t[index] for t in rows)
    return cast(RowsT, type(rows)(*taken) if hasattr(rows, "_fields") else tuple(taken))


def put_rows_(rows: tuple, index: Tensor, new: tuple) -> None:
    """Field by field, write ``new`` ([B, ...]) into the rows ``index`` (B,) int64 of
    ``rows`` ([N, ...] tensors), in place: the work is that of the B rows, every other row is
    untouched. An index may repeat only where its new rows are equal (the result then does
    not depend on the order of the writes)."""
    for t, n in zip(rows, new, strict=True):
        if isinstance(t, tuple):
            put_rows_(t, index, n)
        else:
            t.index_copy_(0, index, n)


def new_episodes(lots: LotDraw, world: World, cfg: ParkingConfig
                 ) -> tuple[ParkingState, Tensor, Tensor]:
    """The paper's reset of B rows: the states of the B drawn ``lots`` (:func:`new_lots`),
    their first observation (B, D) and cost C (B,)."""
    fresh = new_lots(lots, world, cfg)
    return (fresh, *observe(fresh, world, cfg))
