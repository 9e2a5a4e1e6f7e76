"""Run a policy for one episode in each of N lots and record how each ended: the
per-episode runner behind the evaluation report, the tests and the benchmarks."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from torchpark.aids.step import DOCKING_ENGAGED, INTERVENTIONS
from torchpark.sim.observation import NAV_DIM
from torchpark.transforms.features import goal_in_vehicle_frame

# Failure modes: a collision at |v| <= GRAZING_SPEED is "grazing" (the car crept into an
# obstacle); a timeout whose rear axle moved less than FREEZE_DISTANCE over its last
# FREEZE_STEPS steps is "freezing" (the car stopped short of the goal).
GRAZING_SPEED = 1.0  # m/s
FREEZE_DISTANCE = 1.0  # m
FREEZE_STEPS = 100
# One ruler for every agent: the paper's success test C < 4e-4 (~1 mm, 0.1 deg, 4 mm/s),
# C < 4e-3 (about the paper's prose, "1 cm and 1 deg") and C < 4e-2.
SUCCESS_THRESHOLDS = (4e-4, 4e-3, 4e-2)


@dataclass
class Episodes:
    """The first episode of each of N lots. Bool/float tensors (N,) unless stated.

    poses: (T + 1, N, 3) rear-axle poses after each env step from the reset on (rows repeat
    their last pose after their end); final: (N, NAV_DIM) the last observation's [dx, dy,
    cos psi, sin psi, v, cos alpha, sin alpha]; length: env steps taken (an index into ``poses``);
    steps: steps of dt taken (``repeat`` per env step when the env holds its actions);
    braked: the emergency brake stopped or steered (``steer_clear``) at least one of the
    episode's steps of dt (each one a collision in the paper's env, which has no brake; with
    the docking law, the law's count too); docked: the docking law (when on) had taken over
    by the episode's end. Both False for an env without that aid. reached: (N, K) whether
    C fell below each of ``thresholds`` at some step of dt up to the episode's end (a
    collision ends it): the success an env with that looser threshold would have reported,
    exactly, since a looser test only ends the episode sooner on the same trajectory.
    """

    success: torch.Tensor
    collision: torch.Tensor
    timeout: torch.Tensor
    length: torch.Tensor
    final: torch.Tensor
    poses: torch.Tensor
    goal_slot: torch.Tensor
    steps: torch.Tensor
    braked: torch.Tensor
    docked: torch.Tensor
    reached: torch.Tensor
    thresholds: tuple[float, ...] = SUCCESS_THRESHOLDS
    repeat: int = 1

    @property
    def position_error(self) -> torch.Tensor:
        """Distance from the rear axle to its goal at the end, m."""
        return torch.hypot(self.final[:, 0], self.final[:, 1])

    @property
    def heading_error(self) -> torch.Tensor:
        """|wrap(alpha - psi)| at the end, degrees."""
        goal = goal_in_vehicle_frame(self.final)
        return torch.atan2(goal[:, 3], goal[:, 2]).abs() * (180.0 / math.pi)

    @property
    def grazing(self) -> torch.Tensor:
        return self.collision & (self.final[:, 4].abs() <= GRAZING_SPEED)

    @property
    def freezing(self) -> torch.Tensor:
        end = self.length.long()
        rows = torch.arange(end.shape[0])
        before = self.poses[(end - FREEZE_STEPS // self.repeat).clamp(min=0), rows, :2]
        moved = (self.poses[end, rows, :2] - before).norm(dim=-1)
        return self.timeout & (moved < FREEZE_DISTANCE)


def run_episodes(actor: Callable[[TensorDictBase], TensorDictBase], env: TransformedEnv,
                 max_steps: int, desc: str | None = None,
                 thresholds: tuple[float, ...] = SUCCESS_THRESHOLDS,
                 exploration: ExplorationType = ExplorationType.DETERMINISTIC) -> Episodes:
    """Run the policy (deterministic unless ``exploration`` says otherwise, e.g.
    ``ExplorationType.RANDOM``: actions sampled from torch's global generator) until every
    lot's first episode has ended. No row is reset: a row that ended steps on, unrecorded,
    until the last one ends. With ``desc``, a progress bar of the episodes ended so far, so
    labelled (tqdm: ``torchpark[train]``)."""
    base = env.base_env
    n = base.num_envs
    ended = torch.zeros(n, dtype=torch.bool)
    final = torch.zeros(n, NAV_DIM)
    outcome = {key: torch.zeros(n, dtype=torch.bool)
               for key in ("success", "collision", "truncated")}
    length = torch.zeros(n)
    steps = torch.zeros(n)
    braked = torch.zeros(n, dtype=torch.bool)
    docked = torch.zeros(n, dtype=torch.bool)
    limits = torch.tensor(thresholds)
    reached = torch.zeros(n, len(thresholds), dtype=torch.bool)
    td = env.reset()
    poses = [base.state.pose.cpu()]
    bar = None
    if desc is not None:
        from tqdm.auto import tqdm  # a widget in a notebook

        bar = tqdm(total=n, desc=desc, unit="episode", leave=False)
    with set_exploration_type(exploration), torch.no_grad():
        for step in range(1, max_steps + 1):
            td = env.step(actor(td))
            nxt = td["next"]
            first = nxt["done"][:, 0].cpu() & ~ended
            reached |= ~ended[:, None] & (nxt["cost"].cpu() < limits)
            final[first] = nxt["observation"][:, :NAV_DIM].cpu()[first]
            for key in outcome:
                outcome[key] |= first & nxt[key][:, 0].cpu()
            length[first] = step
            # the env's aids' flags, or those a policy composing its own aids wrote beside
            # its action (torchpark.experts.Teacher)
            flags = nxt if DOCKING_ENGAGED in nxt.keys() else td
            if DOCKING_ENGAGED in flags.keys():
                docked[first] = flags[DOCKING_ENGAGED][:, 0].cpu()[first]
            if INTERVENTIONS in flags.keys():
                braked[first] = flags[INTERVENTIONS][:, 0].cpu()[first] > 0
            steps[first] = base.state.steps.cpu()[first].float()
            poses.append(torch.where(ended[:, None], poses[-1], base.state.pose.cpu()))
            ended |= first
            if bar is not None:
                bar.update(int(first.sum()))
            if bool(ended.all()):
                break
            td = step_mdp(td)
    if bar is not None:
        bar.close()
    return Episodes(outcome["success"], outcome["collision"], outcome["truncated"], length,
                    final, torch.stack(poses), base.state.goal_slot.cpu(), steps, braked,
                    docked, reached, tuple(thresholds), base.action_repeat)
