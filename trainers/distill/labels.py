"""The distiller's labelled states: the rollouts, driven by the teacher (behaviour cloning)
or the student (DAgger), noisy on every other row (DART: Laskey et al., 2017), each state
labelled with the teacher's control there and weighted by what followed it (a collision
within a horizon, a stall); the first iteration's final-approach states; one iteration's
data (:func:`label_iteration`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torchrl.envs import Transform, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchpark.aids.config import DockingConfig
from torchpark.aids.starts import near_starts_free
from torchpark.aids.step import AidState
from torchpark.curriculum import PAPER_LEVELS
from torchpark.experts import Teacher
from torchpark.runner import FREEZE_DISTANCE, FREEZE_STEPS
from torchpark.sim.geometry import wrap_angle
from torchpark.transforms.actions import (
    gear_inverse,
    gear_select,
    power_map,
    power_map_inverse,
)
from trainers.distill.config import DaggerConfig

# The student's raw input (before normalisation): the paper's observation, the goal seen
# from the car (torchpark.GoalFrameFeatures) and the features its agent config adds.
STUDENT_INPUT = "observation_policy"
# A stall (steps_in_stall) covers at least this much path, m, in the evaluator's freezing
# window (100 steps of dt): a car rocking at the planner's 2 m/s covers about 20 m.
STALL_TRAVEL = 5.0
# ... from a state more than this far from its goal, m: nearer, the docking law's turns to
# line the car up to the millimetre cover metres of path without going far.
STALL_AWAY = 2.0


def label_iteration(env: TransformedEnv, features: Transform, actor, teacher: Teacher,
                    exponents: torch.Tensor, cfg: DaggerConfig, iteration: int,
                    generator: torch.Generator, teacher_drives: bool
                    ) -> tuple[list[torch.Tensor], int, int]:
    """One DAgger iteration's data: a rollout of ``cfg.steps`` at each occupancy level,
    driven by the teacher where ``teacher_drives`` (a fresh student's iteration 0) and by the
    student otherwise, and in iteration 0 (with
    ``cfg.approach``) the final-approach states. A rollout state's weight is the product of
    ``cfg.collision_weight`` (a collision within ``cfg.collision_horizon`` steps) and
    ``cfg.stall_weight`` (a stall, from ``cfg.stall_from``), each where it holds. Returns
    [inputs (B, D), labels in the student's units (B, 2), weights (B,)], the rollout frames
    and the final-approach states among them. ``env``'s normaliser is frozen after
    iteration 0's rollouts: the teacher's states set the student's input scale."""
    base = env.base_env
    high = base.action_spec.space.high[0]
    batches = []
    frames = approach = 0
    for level in PAPER_LEVELS:
        base.occupancy = level
        r = rollout(env, actor, teacher, exponents, cfg.steps, teacher_drives, cfg.noise,
                    generator)
        stalls = r.stalled & (iteration >= cfg.stall_from)
        batches.append((r.inputs, r.labels,
                        torch.where(r.ahead <= cfg.collision_horizon, cfg.collision_weight, 1.0)
                        * torch.where(stalls, cfg.stall_weight, 1.0)))
        frames += r.inputs.shape[0]
    if iteration == 0:
        env.transform[-1].freeze()
    for level in PAPER_LEVELS if cfg.approach and iteration == 0 else ():
        base.occupancy = level
        x, y = approach_states(env, features, teacher, cfg.approach, cfg.approach_reach,
                               generator)
        batches.append((x, power_map_inverse(y, high, exponents),
                        torch.full((x.shape[0],), cfg.approach_weight, device=x.device)))
        approach += x.shape[0]
    return [torch.cat(column) for column in zip(*batches, strict=True)], frames, approach


def approach_poses(goal: torch.Tensor, reach: float, law: DockingConfig,
                   generator: torch.Generator) -> torch.Tensor:
    """Rear-axle poses (N, 3) in the docking law's final approach to goal poses (N, 3): up to
    ``reach`` m behind the goal along its axis, within ``law.settled_lateral`` m of the axis
    and ``law.settled_heading`` rad of its heading, each as bound * u ** 3 (u uniform in
    [0, 1], sides at random): denser the closer, down to the millimetres of the success
    test."""
    u = torch.rand(goal.shape[0], 3, generator=generator, device=goal.device).pow(3)
    side = torch.where(torch.rand(goal.shape[0], 2, generator=generator, device=goal.device)
                       < 0.5, -1.0, 1.0)
    back = reach * u[:, 0]
    lateral = law.settled_lateral * side[:, 0] * u[:, 1]
    gx, gy, alpha = goal.unbind(-1)
    c, s = torch.cos(alpha), torch.sin(alpha)
    return torch.stack((gx - back * c - lateral * s, gy - back * s + lateral * c,
                        wrap_angle(alpha + law.settled_heading * side[:, 1] * u[:, 2])), -1)


def approach_states(env: TransformedEnv, features: Transform, teacher: Teacher,
                    count: int, reach: float, generator: torch.Generator
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """About ``count`` states of the docking law's final approach (:func:`approach_poses`)
    in fresh lots of ``env`` at its occupancy, those where the car touches nothing, each
    moving at the teacher's speed there times a uniform draw in [0, 2]: the observed speed
    must not give the label away (a student fitted to labels near its observed speed copies
    it, and stays at rest where an episode starts). Returns the student's raw inputs (B, D)
    (``features`` of the observation) and the teacher's controls (B, 2): the law's, engaged
    and driving forwards, or the brake's where it would collide."""
    base, law = env.base_env, teacher.law
    n = base.num_envs
    inputs, labels = [], []
    for _ in range(-(-count // n)):
        env.reset()
        sim = base.state
        pose = approach_poses(sim.goal, reach, law, generator)
        free = near_starts_free(pose[:, None], sim.goal, sim.present, base.world,
                                base.config)[:, 0]
        teacher.state = AidState.zeros(n, base.device)._replace(
            docking_engaged=torch.ones(n, dtype=torch.bool, device=base.device))
        base.set_state(sim._replace(pose=pose))
        control = teacher.label()
        scale = 2.0 * torch.rand(n, generator=generator, device=base.device)
        moving = base.set_state(sim._replace(pose=pose, speed=control[:, 0] * scale))
        inputs.append(features(moving)[STUDENT_INPUT][free])
        labels.append(control[free])
    return torch.cat(inputs), torch.cat(labels)


class Rollout(NamedTuple):
    """A rollout's states (:func:`rollout`), each (steps x N, ...) in step-major order: the
    student's raw inputs (, D); the teacher's labels there in the student's units (, 2); the
    steps of dt to the collision that ends its episode (float; inf where it does not end in
    one within the rollout: :func:`steps_to_collision`); whether the driver stalls from it
    (bool: :func:`steps_in_stall`)."""

    inputs: torch.Tensor
    labels: torch.Tensor
    ahead: torch.Tensor
    stalled: torch.Tensor


def rollout(env: TransformedEnv, actor, teacher: Teacher, exponents: torch.Tensor, steps: int,
            teacher_drives: bool, noise: float, generator: torch.Generator) -> Rollout:
    """``steps`` steps of dt of ``env`` (every row reset first), driven by the teacher's
    labels or the student's deterministic actions, noisy on every other row (Gaussian,
    ``noise`` times the env's bounds, added to the env's action). Labels each state with the
    teacher's control in the student's units (u, the (speed, steer) its power map with
    ``exponents`` turns into them, which the gear head picks by
    :func:`~torchpark.transforms.actions.gear_select`)."""
    n = env.base_env.num_envs
    high = env.base_env.action_spec.space.high[0]
    noisy = (torch.arange(n, device=env.device) % 2 == 1)[:, None]
    inputs, labels, collided, done, positions, goals = ([] for _ in range(6))
    teacher.forget(torch.ones(n, dtype=torch.bool, device=env.device))
    td = env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(steps):
            sim = env.base_env.state
            positions.append(sim.pose[:, :2])
            goals.append(sim.goal[:, :2])
            target = power_map_inverse(teacher.label(), high, exponents)
            inputs.append(td[STUDENT_INPUT])
            labels.append(target)
            action = target
            if not teacher_drives:
                action = actor(td)["action"]
                action = gear_select(action)
            jitter = torch.randn(action.shape, generator=generator, device=action.device)
            control = power_map(action, high, exponents) + noisy * noise * high * jitter
            action = power_map_inverse(control, high, exponents)
            td["action"] = gear_inverse(action)
            td, td_next = env.step_and_maybe_reset(td)
            teacher.forget(td["next", "done"][:, 0])
            collided.append(td["next", "collision"][:, 0])
            done.append(td["next", "done"][:, 0])
            td = td_next
    positions.append(env.base_env.state.pose[:, :2])
    done = torch.stack(done)
    ahead = steps_to_collision(torch.stack(collided), done)
    stalls = steps_in_stall(torch.stack(positions), torch.stack(goals), done)
    return Rollout(torch.cat(inputs), torch.cat(labels), ahead.reshape(-1), stalls.reshape(-1))


def steps_in_stall(positions: torch.Tensor, goals: torch.Tensor, done: torch.Tensor,
                   window: int = FREEZE_STEPS, distance: float = FREEZE_DISTANCE,
                   travel: float = STALL_TRAVEL, away: float = STALL_AWAY) -> torch.Tensor:
    """Per state of a rollout, whether the driver stalls from it, rocking short of its goal:
    the rear axle is more than ``away`` m from the goal, the episode goes on to the
    rollout's end (no park, no collision), and along the next ``window`` steps of dt the
    rear axle covers at least ``travel`` m and ends less than ``distance`` m from where it
    was (the evaluator's freezing, over any ``window`` steps, not only an episode's last,
    of a car that keeps moving; the docking law's turns to line up at the goal are not
    counted).

    ``positions`` (T + 1, N, 2) m: the rear axle before each step and after the last (a
    row's reset start after a step that ended its episode); ``goals`` (T, N, 2) m: the goal
    of each state's episode; ``done`` (T, N) bool: whether the step from state t ended the
    episode. Returns (T, N) bool, False where the episode ends within the rollout or the
    window runs past its end."""
    steps = done.shape[0]
    stalled = torch.zeros_like(done)
    if window > steps:
        return stalled
    ends = torch.cat((torch.zeros_like(done[:1], dtype=torch.long), done.long().cumsum(0)))
    n = steps - window + 1  # the states whose window ends within the rollout
    same = ends[-1] == ends[:n]  # no episode end among steps t .. T - 1
    moved = (positions[window:] - positions[:n]).norm(dim=-1)
    path = torch.cat((torch.zeros_like(positions[:1, :, 0]),
                      (positions[1:] - positions[:-1]).norm(dim=-1).cumsum(0)))
    far = (positions[:n] - goals[:n]).norm(dim=-1) > away
    stalled[:n] = same & far & (moved < distance) & (path[window:] - path[:n] >= travel)
    return stalled


def steps_to_collision(collided: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
    """Per state of a rollout, the steps of dt until its episode ends in a collision.

    ``collided`` / ``done`` (T, N) bool: whether the step from state t of row n collided /
    ended the episode. Returns (T, N) float: 1 where the step from the state collides, k + 1
    where the state after it is k steps from one in the same episode, inf where the episode
    ends without one or runs past the rollout's end."""
    steps = collided.shape[0]
    t = torch.arange(steps, device=collided.device)[:, None]
    ends = torch.where(collided | done, t, steps)
    end = ends.flip(0).cummin(0).values.flip(0)  # the step that ends each state's episode
    hit = collided.gather(0, end.clamp(max=steps - 1)) & (end < steps)
    return torch.where(hit, (end - t + 1).float(), math.inf)


