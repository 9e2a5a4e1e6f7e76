"""The policy alone (``results/policy_alone/``): the hand-written expert (approach planner +
docking law + brake, :mod:`torchpark.experts`) distilled by DAgger into one network that
drives the paper's env with nothing around it.

    python -m trainers.distill TEACHER --out DIR [--iterations 2] [--envs 128] [--steps 400]
                                             [--epochs 32] [--dagger-epochs 16]
                                             [--approach 32768] [--approach-weight 1]
                                             [--seed 0] [--overwrite] [--clearance-features]
                                             [--position] [--settle 0.05] [--retry 1]
                                             [--lr-decay] [--width 512] [--depth 3]
                                             [--gear-hold 0.75] [--gear-features]
                                             [--target-lateral 0.25]
                                             [--target-heading 0.12] [--steer-bins 9]
                                             [--collision-weight 1]
                                             [--collision-horizon 10]
                                             [--stall-weight 1] [--stall-from 1]
                                             [--slot-features] [--resume]

TEACHER is a hybrid checkpoint (``results/fast/checkpoint_final.pt``): its docking law and
brake join the approach planner in the expert (:class:`Teacher`), its network sizes are the
student's unless ``--width`` / ``--depth`` say otherwise.

Each iteration runs a driver in lots at every occupancy level, half the starts near the
goal: the teacher in the first (behaviour cloning), the current student in the later ones
(DAgger). It labels every state visited with the teacher's control there
(:func:`torchpark.aids.step.aided_control`). The labels join the data and the student is
fitted to all of it (DAgger: Ross, Gordon and Bagnell, 2011): ``epochs`` passes after the
first iteration, ``dagger_epochs`` after each later one. Half the rows drive with Gaussian
noise on the control (DART: Laskey et al., 2017), so the data holds the corrections back to
the teacher's path. With ``--collision-weight W`` the states from which the driver collided
within ``--collision-horizon`` steps weigh W in the fit: the student's own collisions,
relabelled, count more than a state it passes. With ``--stall-weight W`` so do the states
the student (not the teacher) then stalls from: more than ``STALL_AWAY`` m from the goal,
in an episode that goes on to the rollout's end, whose next ``FREEZE_STEPS`` steps cover
``STALL_TRAVEL`` m or more and end within ``FREEZE_DISTANCE`` of where they began (the
evaluator's freezing, :mod:`torchpark.runner`, of a car that rocks between the two locks
the teacher would hold).

The last millimetre asks for speeds of mm/s, a ten-thousandth of the range, and a steering
that lines the car up to 0.1 deg. The first iteration therefore also labels ``approach``
states per level drawn in the law's final approach (up to ``approach_reach`` m behind the
goal, within the law's settled lateral and heading errors, denser the closer), weighted
``approach_weight`` times a rollout state. The student's speed passes through a power map
(:class:`torchpark.transforms.actions.PowerActionMap`, ``speed_exponent`` 3): 1 mm/s is 0.058 of
its output's range, not 2e-4. Where the teacher turns a multi-point manoeuvre, states it
drives forwards from and states it reverses from look alike: the student outputs a gear
and a (speed, steer) pair per gear (:class:`torchpark.transforms.actions.GearActionMap`), fitted
to the label's gear and, for that gear's pair only, to the label. The teacher's planner
steers at five fixed angles and switches between them from state to state: with
``--steer-bins`` each gear's steering is a choice among that many bins with an offset in the
bin (:class:`trainers.heads.BinnedGearHead`), fitted as a classification, which keeps the
angle a regression would average.

The student reads the paper's observation and its goal-frame features, normalised (with
``--clearance-features`` the gap along each ray; with ``--position`` the rear axle's (x, y)
in the lot, which the planner's route depends on and the paper's observation lacks; with
``--gear-features`` the gear the car last moved in and its travel in it, counted from the
observed speed, which a teacher's ``--gear-hold`` decides by; with ``--slot-features`` the
gap along each ray to the nearest slot but the goal's, the empty slots the teacher's planner
keeps off and the LIDAR does not see) and acts at every step of dt: no brake, no law, no
held actions.

Written into ``--out``: ``checkpoint_final.pt`` (``python -m trainers.evaluate
DIR/checkpoint_final.pt``), ``checkpoint_best.pt`` (the iteration that scored best on the
checks from uniform starts, :data:`BEST_BY`, on lots that are not the evaluator's: DAgger's
guarantee is for the best policy of the sequence, not the last) and ``dagger.csv``, per
iteration the student's success at the three thresholds on the yardstick (starts 0-6 m
behind the goal, within 1 m and 0.6 rad of the slot axis, empty lot) and from uniform starts
at 0 % and 90 % occupancy. What each setting did: research/experiments.md.

A run longer than a sitting resumes: after each iteration it saves its state
(``dagger_state.pt``: the student, its optimiser, the normaliser, the random generators, the
env's snapshot) and the iteration's labelled states (``dagger_data/``, about 60 MB an
iteration at the defaults, 100 MB the first), and the same command with ``--resume``
continues from the last finished iteration, giving the checkpoints a run never stopped
gives, bit for bit on the same machine and thread count. ``--iterations`` may be raised on
resuming: more DAgger iterations on the same data.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import math
import re
import time
import typing
from dataclasses import dataclass
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.envs import Compose, Transform, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchpark.aids.brake import steer_angles
from torchpark.aids.config import AidsConfig, BrakeConfig, DockingConfig, NearGoalStarts
from torchpark.aids.docking import (
    docking_action,
    docking_phase,
    error_from_goal,
    in_funnel,
    in_settle,
)
from torchpark.aids.starts import near_starts_free
from torchpark.aids.step import AidedState, AidState, aided_control
from torchpark.config import ParkingConfig, check_types, is_integer, positive, require
from torchpark.curriculum import PAPER_LEVELS
from torchpark.experts import ExpertConfig, PlannerConfig
from torchpark.experts.planner import GearHold, grid_of, lot_planner, plan_control
from torchpark.files import directory_arg, locked, save_torch, write_csv
from torchpark.runner import FREEZE_DISTANCE, FREEZE_STEPS, run_episodes
from torchpark.sim.geometry import wrap_angle
from torchpark.sim.layout import build_layout
from torchpark.sim.state import ParkingState
from torchpark.sim.step import move
from torchpark.transforms.actions import (
    GearActionMap,
    PowerActionMap,
    gear_inverse,
    gear_select,
    power_map,
    power_map_inverse,
)
from trainers.checkpoint import load_trained
from trainers.config import AgentConfig, EnvConfig, LoggerConfig, TrainConfig, env_configs
from trainers.heads import BinnedGearHead, imitation_error
from trainers.utils import NORMALISED, build_models, make_base_env, policy_input

# The student's raw input (before normalisation): the paper's observation, the goal seen
# from the car (torchpark.GoalFrameFeatures) and optionally the rays' clearance.
STUDENT_INPUT = "observation_policy"
# A stall (steps_in_stall) covers at least this much path, m, in the evaluator's freezing
# window (100 steps of dt): a car rocking at the planner's 2 m/s covers about 20 m.
STALL_TRAVEL = 5.0
# ... from a state more than this far from its goal, m: nearer, the docking law's turns to
# line the car up to the millimetre cover metres of path without going far.
STALL_AWAY = 2.0
# The teacher's longest look-ahead before its law takes over (Teacher's handover), steps of dt.
HANDOVER_LIMIT = 1000


@dataclass(frozen=True)
class DistillConfig:
    """DAgger's schedule. ``envs`` lots per rollout, ``steps`` steps of dt at each occupancy
    level per iteration; ``near_goal``: the fraction of starts near the goal; ``noise``: the
    std of the Gaussian noise on the noisy rows' actions (in [-1, 1] units); ``yardstick``:
    episodes per check after each iteration; ``approach``: final-approach states labelled
    per level in the first iteration (0: none), drawn up to ``approach_reach`` m behind the
    goal and weighted ``approach_weight`` times a rollout state in the fit;
    ``collision_weight``: the weight of the rollout states from which the driver collides
    within ``collision_horizon`` steps (its own collisions relabelled; 1: as any other);
    ``stall_weight``: of those from which the student stalls (:func:`steps_in_stall`; the
    weights multiply where both hold) in the iterations from ``stall_from`` on (counted from
    0 as in ``dagger.csv``; the teacher's own stalls in iteration 0 are never weighted);
    ``speed_exponent`` / ``steer_exponent``: the student's action map (u in [-1, 1] drives
    high * sign(u) |u| ** exponent); ``clearance_features``: the student also reads the gap
    along each LIDAR ray (torchpark.ClearanceFeatures); ``position``: and its position in
    the lot (torchpark.AidsConfig.observe_position); ``settle``: the teacher's law creeps
    back to the goal from up to ``settle`` m past it
    (:attr:`~torchpark.aids.config.DockingConfig.settle`); ``retry``: only where the test
    can still pass, else it reverses ``retry`` m and drives in again
    (:attr:`~torchpark.aids.config.DockingConfig.retry`); ``reverse_margin``: 0, or the
    teacher's law ends a reversing pass (drives forwards again, as when the brake stops it)
    where reversing that many metres further (at most the thinnest obstacle: the lot's 1 m
    walls) would touch a parked car or a wall (:class:`Teacher`); ``gear_hold``: the teacher's
    planner keeps a new gear for that many metres (``PlannerConfig.gear_hold``, following
    the car the student drives); ``gear_features``: the student also reads the gear and its
    travel in it (torchpark.GearTravelFeatures), so a held gear's labels are a function of
    its input; ``scan_memory``: 0, or the student also reads the nearest ray end in each
    ray's sector over this scan and that many before it (torchpark.ScanMemory);
    ``slot_features``: and, per ray, the gap to the nearest slot but the goal's
    (torchpark.SlotGaps; with ``position``), the slots its teacher keeps off;
    ``steer_bins``: 0, or the bins of the student's steering
    (``ModelConfig.steer_bins``, :class:`trainers.heads.BinnedGearHead`);
    ``target_lateral`` / ``target_heading``: the planner's
    target, where the law takes over, within that many metres of the slot axis and radians
    of the goal's heading (``PlannerConfig.lateral`` / ``heading``; None: the planner's
    default; a tight target leaves the law little to turn, so the brake seldom acts);
    ``planner_headings``: the planner's grid of headings (``PlannerConfig.headings``; None:
    its default); ``funnel_lateral`` / ``funnel_heading``: the law's funnel, wider than the
    target (``PlannerConfig.law_lateral`` / ``law_heading``; None: the target's);
    ``handover``: 0, or the steps of dt the teacher simulates its law ahead before it takes
    over beyond the target (:class:`Teacher`); ``car_margin``: the teacher's planner keeps
    its car box, grown by that many metres, off the parked cars and walls it is clear of
    (``PlannerConfig.car_margin``);
    ``lr_decay``: each fit's learning
    rate falls from ``lr`` to 0 along a cosine; ``epochs`` / ``dagger_epochs``: passes over
    the data after the first / each later iteration; ``width`` / ``depth``: the student's
    hidden layers (None: the teacher's sizes)."""

    iterations: int = 2
    envs: int = 128
    steps: int = 400
    epochs: int = 32
    dagger_epochs: int = 16
    batch_size: int = 1024
    lr: float = 1e-3
    near_goal: float = 0.5
    noise: float = 0.05
    approach: int = 32768
    approach_reach: float = 2.0
    approach_weight: float = 1.0
    collision_weight: float = 1.0
    collision_horizon: int = 10
    stall_weight: float = 1.0
    stall_from: int = 1
    lr_decay: bool = False
    speed_exponent: float = 3.0
    steer_exponent: float = 1.0
    clearance_features: bool = False
    position: bool = False
    settle: float = 0.0
    retry: float = 0.0
    reverse_margin: float = 0.0
    gear_hold: float = 0.0
    gear_features: bool = False
    scan_memory: int = 0
    slot_features: bool = False
    steer_bins: int = 0
    target_lateral: float | None = None
    target_heading: float | None = None
    planner_headings: int | None = None
    funnel_lateral: float | None = None
    funnel_heading: float | None = None
    handover: int = 0
    car_margin: float = 0.0
    width: int | None = None
    depth: int | None = None
    yardstick: int = 200
    seed: int = 0

    def __post_init__(self) -> None:
        check_types(self)
        for name, high in (("iterations", 1000), ("envs", 65536), ("steps", 100_000),
                           ("epochs", 1000), ("dagger_epochs", 1000), ("batch_size", 1 << 20),
                           ("yardstick", 65536), ("collision_horizon", 1000),
                           ("stall_from", 1000)):
            value = getattr(self, name)
            require(1 <= value <= high, f"DistillConfig.{name}", f"an int in [1, {high}]",
                    value)
        require(0 <= self.approach <= 1 << 20, "DistillConfig.approach",
                "an int in [0, 1048576]", self.approach)
        for name in ("lr", "approach_reach", "approach_weight", "collision_weight",
                     "stall_weight"):
            positive(f"DistillConfig.{name}", getattr(self, name))
        for name in ("speed_exponent", "steer_exponent"):
            value = getattr(self, name)
            require(1.0 <= value <= 8.0, f"DistillConfig.{name}", "in [1, 8]", value)
        require(0.0 <= self.near_goal <= 1.0, "DistillConfig.near_goal", "in [0, 1]",
                self.near_goal)
        require(0.0 <= self.noise <= 1.0, "DistillConfig.noise", "in [0, 1]", self.noise)
        # reverse_margin's upper bound is the env's lot's: Teacher checks it
        for name in ("settle", "retry", "reverse_margin", "gear_hold", "car_margin"):
            value = getattr(self, name)
            require(0.0 <= value < float("inf"), f"DistillConfig.{name}", "finite, >= 0 (m)",
                    value)
        # the funnel's lower bounds (the target's) are PlannerConfig's to check
        for name, (high, unit) in (("target_lateral", (math.inf, "m")),
                                   ("target_heading", (math.pi, "rad")),
                                   ("funnel_lateral", (math.inf, "m")),
                                   ("funnel_heading", (math.pi, "rad"))):
            value = getattr(self, name)
            require(value is None or (math.isfinite(value) and 0.0 < value <= high),
                    f"DistillConfig.{name}", f"None or finite, in (0, {high:g}] ({unit})",
                    value)
        require(0 <= self.scan_memory <= 64, "DistillConfig.scan_memory",
                "an int in [0, 64]", self.scan_memory)
        require(not self.slot_features or self.position, "DistillConfig.slot_features",
                "False without position (the slots are found from the car's position)",
                self.slot_features)
        require(self.steer_bins == 0 or (3 <= self.steer_bins <= 255
                                         and self.steer_bins % 2 == 1),
                "DistillConfig.steer_bins", "0, or an odd int in [3, 255]", self.steer_bins)
        require(0 <= self.handover <= HANDOVER_LIMIT, "DistillConfig.handover",
                f"an int in [0, {HANDOVER_LIMIT}]", self.handover)
        require(self.planner_headings is None or 8 <= self.planner_headings <= 1024,
                "DistillConfig.planner_headings", "None or an int in [8, 1024]",
                self.planner_headings)
        for name, high in (("width", 4096), ("depth", 8)):
            value = getattr(self, name)
            require(value is None or 1 <= value <= high, f"DistillConfig.{name}",
                    f"None or an int in [1, {high}]", value)
        teacher_planner(self)  # the planner's own bounds between them (the funnel's)

class Teacher:
    """The hand-written expert's control at any state of a paper's env (its lots, its world):
    the approach planner (:mod:`torchpark.experts.planner`) up to its own target, the docking
    law there (a hybrid checkpoint's, creeping back to the goal from up to ``settle`` m past
    it and, with ``retry``, backing out ``retry`` m where the test cannot pass), the
    checkpoint's brake under both. ``planner``: its grid and costs (the default's tables
    take about two minutes to build; tests pass a coarse grid). ``reverse_margin`` m: 0, or
    the law's reversing pass, which otherwise runs until the brake stops it at contact,
    turns forwards where the car's box moved that far straight back would touch a parked
    car or a wall: the label changes gear with room to spare, which a student a few steps
    late still has (at most the lot's thinnest obstacle, which the look-ahead must not step
    over; refused beyond). ``handover`` steps of dt: 0, the law takes over anywhere in its
    funnel (``planner.law_*``); H > 0, beyond the planner's own target (where it always does)
    only where the law itself, simulated H steps on from there (its reversing passes ending
    ``reverse_margin`` short as in the labels), touches nothing: a funnel wider than the
    target ends the planner's stalls short of it without handing the law a turn-in it could
    only finish with the brake.

    ``label()`` returns the (N, 2) control (v m/s, delta rad) the expert would drive with at
    the env's state, and advances the brake's flag as if it had (``intervened``: where the
    brake stopped or steered it). Its labels are a function
    of what the student sees: the law drives wherever the car is in its funnel (not from the
    moment it entered to the episode's end) and in the gear the car moves in (not the pass it
    began), so a student off the teacher's path is not told to reverse where the same pose,
    moving forwards, is told to go on. ``forget(rows)`` clears the aids' state where
    episodes ended."""

    def __init__(self, path: str, env: TransformedEnv, settle: float = 0.0,
                 retry: float = 0.0, planner: PlannerConfig | None = None,
                 reverse_margin: float = 0.0, handover: int = 0) -> None:
        cfg, _ = load_trained(path)
        _, aids = env_configs(cfg, training=False)
        if aids is None or aids.docking is None:
            raise ValueError(f"teacher {path!r} has no docking law to take over from the "
                             f"planner: distil a hybrid agent with one")
        self.expert = ExpertConfig(
            planner=planner if planner is not None else PlannerConfig(),
            docking=dataclasses.replace(aids.docking, settle=settle, retry=retry),
            brake=aids.brake)
        self.aids = self.expert.aids()
        self.base = env.base_env
        config = self.base.config
        # the look-ahead tests the one pose reverse_margin m back: no further than the
        # thinnest obstacle, or it could step over one
        thinnest = config.lot.thinnest_obstacle
        require(0.0 <= reverse_margin <= thinnest, "reverse_margin",
                f"in [0, {thinnest:g}] m (LotConfig.thinnest_obstacle, min(wall_thickness, "
                f"car_width))", reverse_margin)
        self.reverse_margin = reverse_margin
        require(is_integer(handover) and 0 <= handover <= HANDOVER_LIMIT, "handover",
                f"an int in [0, {HANDOVER_LIMIT}] (steps of dt)", handover)
        self.handover = handover
        # with a look-ahead the law's own funnel is the planner's target, and the wider one
        # is entered only where the look-ahead is clear
        self.funnel = self.aids.docking
        if handover:
            target = self.expert.planner
            self.aids = dataclasses.replace(self.aids, docking=dataclasses.replace(
                self.funnel, reach=target.reach, lateral=target.lateral,
                heading=target.heading))
        self.planner = lot_planner(config.lot, config.vehicle, self.expert.planner,
                                   str(self.base.device))
        self.angles = steer_angles(config, self.aids.brake or BrakeConfig(), self.base.device)
        self.hold = GearHold(self.expert.planner.gear_hold, self.base.num_envs, self.base.device)
        self.state = AidState.zeros(self.base.num_envs, self.base.device)
        # (N,) bool: the brake stopped or steered the last label
        self.intervened = torch.zeros(self.base.num_envs, dtype=torch.bool,
                                      device=self.base.device)

    def ends_short(self, pose: torch.Tensor, reverses: torch.Tensor, present: torch.Tensor
                   ) -> torch.Tensor:
        """Where a reversing pass ends short of contact (``reverse_margin``), bool (n,): the
        rows of ``reverses`` (n,) whose car box at ``pose`` (n, 3), moved that far straight
        back, would touch an obstacle of ``present`` (n, M); none without a margin."""
        if self.reverse_margin == 0:
            return torch.zeros_like(reverses)
        config = self.base.config
        back = torch.full_like(pose[:, 0], -self.reverse_margin / config.vehicle.dt)
        _, near = move(pose, back, torch.zeros_like(back), present, self.base.world, config)
        return reverses & near

    def law_is_clear(self, sim: ParkingState, rows: torch.Tensor) -> torch.Tensor:
        """Whether the law, driving from the cars of ``rows`` (n,) int64 in the gear each
        moves in, goes ``handover`` steps of dt without touching an obstacle, bool (n,)."""
        config, law = self.base.config, self.aids.docking
        pose, goal, present = sim.pose[rows], sim.goal[rows], sim.present[rows]
        reverses = sim.speed[rows] < 0
        engaged = torch.ones_like(reverses)
        braked, clear = torch.zeros_like(reverses), torch.ones_like(reverses)
        for _ in range(self.handover):
            error = error_from_goal(pose, goal)
            braked = braked | self.ends_short(pose, reverses, present)
            _, reverses = docking_phase(error, engaged, reverses, braked, law)
            v, delta = docking_action(error, reverses, law, config.vehicle)
            ahead, braked = move(pose, v, delta, present, self.base.world, config)
            clear = clear & ~braked
            pose = torch.where(braked[:, None], pose, ahead)
        return clear

    @torch.no_grad()
    def label(self) -> torch.Tensor:
        sim, law = self.base.state, self.aids.docking
        error = error_from_goal(sim.pose, sim.goal)
        funnel = in_funnel(error, law) | in_settle(error, law)
        if self.handover:
            rows = (in_funnel(error, self.funnel) & ~funnel).nonzero()[:, 0]
            funnel = funnel.index_put((rows,), self.law_is_clear(sim, rows))
        reverses = funnel & (sim.speed < 0)
        # the pass ends short of contact, as if braked there
        braked = self.state.braked | self.ends_short(sim.pose, reverses, sim.present)
        self.state = self.state._replace(braked=braked, docking_engaged=funnel,
                                         docking_reverses=reverses)
        # the gear the car (the student) moves in, held
        action = torch.stack(plan_control(self.planner, sim.pose, sim.speed, sim.goal_slot,
                                          self.hold.keep_in(sim, self.base),
                                          (self.base.world, sim.present))[:2], -1)
        control = aided_control(AidedState(sim, self.state), action,
                                self.base.world, self.angles, self.base.config, self.aids)
        self.state, self.intervened = control.aids, control.intervened
        return torch.stack([control.speed, control.steer], dim=-1)

    def forget(self, rows: torch.Tensor) -> None:
        self.state = AidState(*(torch.where(rows, torch.zeros_like(f), f) for f in self.state))


def student_config(teacher: str, cfg: DistillConfig) -> TrainConfig:
    """The student's TrainConfig: the paper's env and agent (no aid, one action per step of
    dt) with the goal features (and the clearance features and position, if asked) and the
    power action map of ``speed_exponent`` / ``steer_exponent``, the teacher's network sizes
    (each hidden layer ``width`` wide and ``depth`` of them, where given); training starts
    near the goal with probability ``near_goal``."""
    tcfg, _ = load_trained(teacher)
    hidden = list(tcfg.model.hidden)
    if cfg.width is not None or cfg.depth is not None:
        hidden = [cfg.width or hidden[0]] * (cfg.depth or len(hidden))
    student = TrainConfig(
        env=EnvConfig(num_envs=cfg.envs,
                      task=ParkingConfig(max_steps=tcfg.env.task.max_steps)),
        agent=AgentConfig(
            aids=AidsConfig(observe_position=cfg.position, near_goal_starts=NearGoalStarts(
                probability=cfg.near_goal) if cfg.near_goal > 0 else None),
            action_exponents=[cfg.speed_exponent, cfg.steer_exponent], gear_head=True,
            goal_features=True, clearance_features=cfg.clearance_features,
            gear_features=cfg.gear_features, scan_memory=cfg.scan_memory,
            slot_features=cfg.slot_features),
        model=dataclasses.replace(tcfg.model, hidden=hidden, steer_bins=cfg.steer_bins),
        logger=LoggerConfig(exp_name="distilled"), seed=cfg.seed)
    return student


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
    base, law = env.base_env, teacher.aids.docking
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


def rollout(env: TransformedEnv, actor, teacher: Teacher, exponents: torch.Tensor, steps: int,
            teacher_drives: bool, noise: float, generator: torch.Generator
            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``steps`` steps of dt of ``env`` (every row reset first), driven by the teacher's
    labels or the student's deterministic actions, noisy on every other row (Gaussian,
    ``noise`` times the env's bounds, added to the env's action). Returns the student's raw
    inputs (steps x N, D), the teacher's labels there in the student's units (u, the
    (speed, steer) its power map with ``exponents`` turns into them, which the gear head
    picks by :func:`~torchpark.transforms.actions.gear_select`), per state, the steps
    of dt to the collision that ends its episode (steps x N,; inf where the episode does
    not end in one within the rollout: :func:`steps_to_collision`) and whether the driver
    stalls from it (steps x N, bool: :func:`steps_in_stall`)."""
    n = env.base_env.num_envs
    high = env.base_env.action_spec.space.high[0]
    noisy = (torch.arange(n, device=env.device) % 2 == 1)[:, None]
    inputs, labels, collided, done, positions, goals = [], [], [], [], [], []
    teacher.forget(torch.ones(n, dtype=torch.bool, device=env.device))
    td = env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(steps):
            positions.append(env.base_env.state.pose[:, :2])
            goals.append(env.base_env.state.goal[:, :2])
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
    return torch.cat(inputs), torch.cat(labels), ahead.reshape(-1), stalls.reshape(-1)


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


def fit(actor, norm, inputs: torch.Tensor, labels: torch.Tensor, weights: torch.Tensor,
        epochs: int, cfg: DistillConfig, optim: torch.optim.Optimizer,
        generator: torch.Generator) -> float:
    """``epochs`` passes of minibatch regression of the student's deterministic action (tanh
    of its loc) on the labels (N, 2) (:func:`imitation_error`, or the binned steering's own,
    :meth:`trainers.heads.BinnedGearHead.imitation_error`; weighted per state by ``weights``
    (N,)), the learning rate from ``cfg.lr`` (to 0 along a cosine with
    ``cfg.lr_decay``); returns the last epoch's mean loss."""
    net = actor.module[0]
    body = net.module[0]  # the policy's network before its scale head
    for group in optim.param_groups:
        group["lr"] = cfg.lr
    batches = epochs * -(-inputs.shape[0] // cfg.batch_size)
    schedule = (torch.optim.lr_scheduler.CosineAnnealingLR(optim, batches) if cfg.lr_decay
                else None)
    losses = []
    for _ in range(epochs):
        losses = []
        for index in torch.randperm(inputs.shape[0], generator=generator).split(cfg.batch_size):
            td = norm(TensorDict({STUDENT_INPUT: inputs[index]}, [index.shape[0]]))
            if isinstance(body, BinnedGearHead):
                error = body.imitation_error(td[NORMALISED], labels[index])
            else:
                error = imitation_error(torch.tanh(net(td)["loc"]), labels[index])
            loss = (weights[index] * error).mean()
            optim.zero_grad()
            loss.backward()
            optim.step()
            if schedule is not None:
                schedule.step()
            losses.append(loss.detach())
    return torch.stack(losses).mean().item()


# What a run writes into --out (none is replaced without --overwrite).
OUTPUTS = ("checkpoint_final.pt", "checkpoint_best.pt", "dagger.csv", "dagger_state.pt")
# What --resume continues from: the run's state after its last finished iteration, and each
# iteration's labelled states (inputs, labels, weights), in this folder.
STATE, DATA = "dagger_state.pt", "dagger_data"
# The checks that pick checkpoint_best.pt: the paper's test from uniform starts, empty and
# at 90 % (their sum).
BEST_BY = ("uniform_0_0.0004", "uniform_90_0.0004")


def score(row: dict) -> float:
    """A DAgger iteration's score: the sum of its BEST_BY checks."""
    return sum(row[key] for key in BEST_BY)


def check(actor, scfg: TrainConfig, obs_norm: dict, episodes: int, seed: int
          ) -> dict[str, float]:
    """The student on the yardstick (near-goal starts, empty lot) and from uniform starts at
    0 % and 90 %: success at the three thresholds and collisions."""
    row = {}
    for name, near, occupancy in (("yardstick", 1.0, 0.0), ("uniform_0", 0.0, 0.0),
                                  ("uniform_90", 0.0, 0.9)):
        aids = dataclasses.replace(scfg.agent.aids, near_goal_starts=None if near == 0 else
                                   NearGoalStarts(probability=near))
        cfg = dataclasses.replace(scfg, agent=dataclasses.replace(scfg.agent, aids=aids))
        base = make_base_env(cfg, training=True, num_envs=episodes, seed=seed)
        base.occupancy = occupancy
        inputs = policy_input(cfg, base)
        env = TransformedEnv(base, Compose(*inputs))
        inputs[-1].load_state_dict(obs_norm)
        inputs[-1].freeze()
        run = run_episodes(actor, env, cfg.env.task.max_steps)
        for k, threshold in enumerate(run.thresholds):
            row[f"{name}_{threshold:g}"] = run.reached[:, k].float().mean().item()
        row[f"{name}_collision"] = run.collision.float().mean().item()
    return row


def run_state(out: Path, teacher_path: str, cfg: DistillConfig) -> dict:
    """The state a run in ``out`` saved after its last finished iteration (:data:`STATE`),
    checked to be of this teacher and these settings (``iterations`` aside: a run may be
    continued to more), its data files present. Tensors and plain data only."""
    path = out / STATE
    if not path.exists():
        raise ValueError(f"--resume: {path} does not exist (no run to continue in {out})")
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
        theirs, digest = dict(saved["distill"]), saved["teacher"]
        done = int(saved["iterations_done"])
    except Exception as err:  # not a torch file, not plain data, or not this layout
        raise ValueError(f"--resume: {path} is not a distiller's state "
                         f"({type(err).__name__})") from None
    ours = dataclasses.asdict(cfg)
    # A setting added since the run was saved holds its default there.
    theirs = {**{f.name: f.default for f in dataclasses.fields(DistillConfig)}, **theirs}
    gone = sorted(set(theirs) - set(ours))
    if gone:
        raise ValueError(f"--resume: the run in {out} has {gone[0]}={theirs[gone[0]]!r}, a "
                         f"setting this distiller no longer has (resume it at the commit "
                         f"that started it)")
    differs = sorted(k for k in set(ours) | set(theirs)
                     if k != "iterations" and ours.get(k) != theirs.get(k))
    if differs:
        key = differs[0]
        raise ValueError(f"--resume: the run in {out} has {key}={theirs.get(key)!r}, this "
                         f"command {key}={ours.get(key)!r} (only --iterations may change)")
    if digest != teacher_digest(teacher_path):
        raise ValueError(f"--resume: the run in {out} was distilled from another teacher "
                         f"than {teacher_path}")
    if cfg.iterations < done:
        raise ValueError(f"--iterations must be >= {done}, the iterations the run in {out} "
                         f"has finished, got {cfg.iterations}")
    missing = [k for k in range(done) if not data_path(out, k).exists()]
    if missing:
        raise ValueError(f"--resume: {data_path(out, missing[0])} is missing (the run's "
                         f"labelled data)")
    return saved


def teacher_digest(path: str) -> str:
    """The SHA-256 of the teacher's checkpoint file (a resumed run must have the same)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def load_data(out: Path, iteration: int, device: torch.device) -> list[torch.Tensor]:
    """The (inputs, labels, weights) labelled in ``iteration`` of the run in ``out``."""
    path = data_path(out, iteration)
    try:
        inputs, labels, weights = torch.load(path, map_location=device, weights_only=True)
    except Exception as err:  # not a torch file, not plain data, or not three tensors
        raise ValueError(f"--resume: {path} is not a distiller's labelled data "
                         f"({type(err).__name__})") from None
    return [inputs, labels, weights]


def data_path(out: Path, iteration: int) -> Path:
    """Where the states labelled in ``iteration`` are kept for a resumed run."""
    return out / DATA / f"iteration_{iteration:03d}.pt"


def teacher_planner(cfg: DistillConfig, planner: PlannerConfig | None = None
                    ) -> PlannerConfig:
    """The teacher's planner: ``planner`` (default :class:`PlannerConfig`) with the run's gear
    hold and car margin and, where set, its target's lateral and heading bounds, its headings
    and the law's funnel."""
    given = {name: getattr(cfg, ours) for name, ours in PLANNER_FIELDS.items()
             if getattr(cfg, ours) is not None}
    try:
        return dataclasses.replace(planner or PlannerConfig(), **given)
    except ValueError as err:  # in the words of the run's own settings and flags
        text = re.sub(r"PlannerConfig\.(\w+)", lambda m: _our_field(m.group(1)), str(err))
        raise ValueError(re.sub(r"\[(\w+) = ", lambda m: f"[{_our_field(m.group(1), False)} = ",
                                text)) from None


# The teacher's planner's settings a run sets (PlannerConfig's name: DistillConfig's).
PLANNER_FIELDS = {"lateral": "target_lateral", "heading": "target_heading",
                  "headings": "planner_headings", "law_lateral": "funnel_lateral",
                  "law_heading": "funnel_heading", "gear_hold": "gear_hold",
                  "car_margin": "car_margin"}


def _our_field(planner_name: str, flag: bool = True) -> str:
    """A PlannerConfig field's name as the run's setting (and its flag) that sets it."""
    ours = PLANNER_FIELDS.get(planner_name)
    if ours is None:
        return f"PlannerConfig.{planner_name}"
    return f"DistillConfig.{ours}" + (f" (--{ours.replace('_', '-')})" if flag else "")


def distill(teacher_path: str, out: Path, cfg: DistillConfig,
            planner: PlannerConfig | None = None, resume: bool = False) -> Path:
    """Run DAgger; returns the final checkpoint's path. ``planner``: the teacher's
    (:class:`Teacher`). After each iteration the run's state (the student, its optimiser,
    the normaliser, the random generators, the env's snapshot, the rows of ``dagger.csv``)
    goes to ``out/``:data:`STATE` and the iteration's labelled states to ``out/``:data:`DATA`;
    ``resume`` continues from them exactly (the same checkpoints as a run never stopped,
    bit for bit), to ``cfg.iterations``."""
    scfg = student_config(teacher_path, cfg)
    saved = run_state(out, teacher_path, cfg) if resume else None
    digest = teacher_digest(teacher_path)
    torch.manual_seed(cfg.seed)
    generator = torch.Generator().manual_seed(cfg.seed)
    base = make_base_env(scfg, training=True)
    high = base.action_spec.space.high[0]
    inputs = policy_input(scfg, base)
    env = TransformedEnv(base, Compose(*inputs))
    norm = inputs[-1]
    # The student's feature transforms (between the action maps and the normaliser), applied
    # outside the env to the final-approach states.
    features = Compose(*[t.clone() for t in inputs[:-1]
                         if not isinstance(t, (PowerActionMap, GearActionMap))])
    actor, _ = build_models(scfg)
    exponents = torch.tensor([cfg.speed_exponent, cfg.steer_exponent], device=base.device)
    plan = teacher_planner(cfg, planner)
    cells = grid_of(build_layout(base.config.lot, base.config.vehicle, "cpu"), plan).cells
    print(f"the teacher's planner: its cost-to-go tables over {cells:,} cells (about 3 min on "
          f"two cores at the default grid; --planner-headings fewer for a coarser one) ...",
          flush=True)
    started_tables = time.perf_counter()
    teacher = Teacher(teacher_path, env, cfg.settle, cfg.retry, plan, cfg.reverse_margin,
                      cfg.handover)
    print(f"the teacher's planner ready in {time.perf_counter() - started_tables:.0f} s",
          flush=True)
    optim = torch.optim.Adam(actor.parameters(), lr=cfg.lr)
    data, rows = [], []  # (inputs, labels, weights) per iteration
    frames = approach = first = 0
    elapsed = 0.0
    if saved is not None:
        first, frames, approach = (saved[k] for k in ("iterations_done", "frames",
                                                       "approach_states"))
        rows, elapsed = saved["rows"], saved["wall_s"]
        actor.load_state_dict(saved["actor"])
        optim.load_state_dict(saved["optim"])
        norm.load_state_dict(saved["obs_norm"])
        norm.freeze()
        generator.set_state(saved["generator"])
        torch.set_rng_state(saved["torch_rng"])
        base.restore(saved["env"])
        data = [load_data(out, k, base.device) for k in range(first)]
        print(f"resumed after iteration {first} of {cfg.iterations} ({frames:,} labelled "
              f"frames)", flush=True)
    parts = [name for name, on in (("gear head", True),
                                   ("clearance features", cfg.clearance_features),
                                   ("gear features", cfg.gear_features),
                                   (f"a memory of {cfg.scan_memory} scans",
                                    cfg.scan_memory > 0),
                                   ("slot features", cfg.slot_features),
                                   ("binned steering", cfg.steer_bins > 0),
                                   ("position", cfg.position)) if on]
    made_of = f" ({', '.join(parts)})" if parts else ""
    source = f"the approach planner with the aids of {teacher_path}"
    if cfg.settle:
        source += f" (its law creeping to the goal within {cfg.settle:g} m"
        source += f", retrying {cfg.retry:g} m back where the test cannot pass)" if cfg.retry \
            else ")"
    if cfg.reverse_margin:
        source += f" (its law's reversing passes ending {cfg.reverse_margin:g} m short of contact)"
    if cfg.car_margin:
        source += f" (its planner keeping {cfg.car_margin:g} m off the parked cars)"
    if cfg.handover:
        source += (f" (its law taking over beyond the target only where {cfg.handover} steps of "
                   f"it ahead touch nothing)")
    dagger = "DAgger after the first"
    if cfg.collision_weight != 1.0:
        dagger += (f"; the states up to {cfg.collision_horizon} steps before its own "
                   f"collisions weighted {cfg.collision_weight:g}")
    if cfg.stall_weight != 1.0:
        dagger += f"; the states it stalls from weighted {cfg.stall_weight:g}"
        if cfg.stall_from != 1:
            dagger += f" from iteration {cfg.stall_from}"
    started = time.perf_counter() - elapsed
    for iteration in range(first, cfg.iterations):
        batches = []
        for level in PAPER_LEVELS:
            base.occupancy = level
            x, y, ahead, stalled = rollout(env, actor, teacher, exponents, cfg.steps,
                                           iteration == 0, cfg.noise, generator)
            stalls = stalled & (iteration >= cfg.stall_from)
            batches.append((x, y, torch.where(ahead <= cfg.collision_horizon,
                                              cfg.collision_weight, 1.0)
                            * torch.where(stalls, cfg.stall_weight, 1.0)))
            frames += x.shape[0]
        if iteration == 0:
            norm.freeze()  # the teacher's states set the student's input scale
        for level in PAPER_LEVELS if cfg.approach and iteration == 0 else ():
            base.occupancy = level
            x, y = approach_states(env, features, teacher, cfg.approach, cfg.approach_reach,
                                   generator)
            batches.append((x, power_map_inverse(y, high, exponents),
                            torch.full((x.shape[0],), cfg.approach_weight, device=x.device)))
            approach += x.shape[0]
        data.append([torch.cat(column) for column in zip(*batches, strict=True)])
        data_path(out, iteration).parent.mkdir(exist_ok=True)
        save_torch(data[-1], data_path(out, iteration))
        x, y, w = (torch.cat(column) for column in zip(*data, strict=True))
        epochs = cfg.epochs if iteration == 0 else cfg.dagger_epochs
        loss = fit(actor, norm.to_observation_norm(), x, y, w, epochs, cfg, optim, generator)
        row = {"iteration": iteration, "frames": frames, "approach_states": approach,
               "samples": x.shape[0], "loss": loss,
               **check(actor, scfg, norm.state_dict(), cfg.yardstick, cfg.seed + 1000),
               "wall_s": time.perf_counter() - started}
        rows.append(row)
        print(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                       for k, v in row.items()), flush=True)
        write_csv(out / "dagger.csv", rows, list(row))
        checkpoint = {"config": dataclasses.asdict(scfg), "frames": frames,
                      "actor": actor.state_dict(), "obs_norm": norm.state_dict(),
                      "trained_by": f"distilled{made_of} from {source}: "
                                    f"{iteration + 1} iteration(s) ({dagger}), "
                                    f"{frames:,} labelled frames and {approach:,} "
                                    f"final-approach states"}
        save_torch(checkpoint, out / "checkpoint_final.pt")
        if score(row) >= max(map(score, rows)):
            save_torch(checkpoint, out / "checkpoint_best.pt")
        # Last: a run killed before this line resumes from the iteration before, whose
        # files the redone iteration rewrites as they were.
        save_torch({"distill": dataclasses.asdict(cfg), "teacher": digest,
                    "iterations_done": iteration + 1, "frames": frames,
                    "approach_states": approach, "rows": rows, "wall_s": row["wall_s"],
                    "actor": actor.state_dict(), "optim": optim.state_dict(),
                    "obs_norm": norm.state_dict(), "generator": generator.get_state(),
                    "torch_rng": torch.get_rng_state(), "env": base.snapshot()},
                   out / STATE)
    return out / "checkpoint_final.pt"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m trainers.distill",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("teacher", help="a hybrid agent's checkpoint (e.g. "
                                        "results/fast/checkpoint_final.pt)")
    parser.add_argument("--out", required=True, type=directory_arg,
                        help="directory of the student's files")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the outputs already in --out (refused by default)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out from its last finished iteration, "
                             "exactly (the same teacher and settings; --iterations may be "
                             "raised)")
    hints = typing.get_type_hints(DistillConfig)
    for field in dataclasses.fields(DistillConfig):
        flag = f"--{field.name.replace('_', '-')}"
        if isinstance(field.default, bool):  # --gear-head / --no-gear-head
            parser.add_argument(flag, action=argparse.BooleanOptionalAction,
                                default=field.default)
            continue
        # int, float, or the X of an ``X | None``
        kind = next(k for k in typing.get_args(hints[field.name]) or (hints[field.name],)
                    if k is not type(None))
        parser.add_argument(flag, type=kind, default=field.default)
    args = parser.parse_args(argv)
    out = args.out
    try:
        cfg = DistillConfig(**{f.name: getattr(args, f.name)
                               for f in dataclasses.fields(DistillConfig)})
        if args.resume and args.overwrite:
            raise ValueError("--resume continues the run in --out, --overwrite replaces it: "
                             "pass one of them")
        with locked(out, "--out"):
            existing = [name for name in OUTPUTS if (out / name).exists()]
            if existing and not (args.overwrite or args.resume):
                raise ValueError(f"{out / existing[0]} exists ({len(existing)} of the outputs "
                                 f"do): pass another --out, or --overwrite to replace them")
            print(distill(args.teacher, out, cfg, resume=args.resume))
    except (ValueError, OSError) as err:
        parser.exit(2, f"{parser.prog}: error: {str(err).splitlines()[0]}\n")


if __name__ == "__main__":
    main()
