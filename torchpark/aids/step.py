"""The agent's step and reset: the paper's (:mod:`torchpark.sim.step`) with the configured aids
composed around the same commit of a state. The env holds one state whatever the aids, an
:class:`AidedState` (the paper's state and the aids' beside it, inert when they are off, as
Brax keeps a wrapper's state in ``state.info``); :func:`agent_step` picks the paper's own
step, lifted onto it, when there is no aid."""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import torch
from torch import Tensor
from torchrl.data import Binary, TensorSpec, Unbounded

from torchpark.aids.brake import apply_brake, check_margin, steer_angles
from torchpark.aids.config import AidsConfig
from torchpark.aids.docking import take_over
from torchpark.aids.repeat import StepFn, hold
from torchpark.aids.starts import NearDraw, near_start
from torchpark.config import ParkingConfig
from torchpark.sim.episodes import LotDraw
from torchpark.sim.observation import observe
from torchpark.sim.records import replace
from torchpark.sim.state import ParkingState, StepResult
from torchpark.sim.step import commit, move, new_episodes, new_lots, parking_step
from torchpark.sim.vehicle import clamp_action
from torchpark.sim.world import World

# The aids' per-step outputs (ParkingEnv declares those of the aids it has), (N, 1) each:
# the brake stopped the last step of dt (bool), the steps of dt it stopped or steered this
# episode (int64); the docking law drives this episode (bool).
BRAKED, INTERVENTIONS, DOCKING_ENGAGED = "braked", "interventions", "docking_engaged"
POSITION = "position"  # with AidsConfig.observe_position: the rear axle's (x, y)
BRAKE_KEYS = (BRAKED, INTERVENTIONS)
DOCKING_KEYS = (DOCKING_ENGAGED,)


def output_keys(aids: AidsConfig) -> tuple[str, ...]:
    """The aids' per-step outputs (N, 1) an env with ``aids`` emits, read from its
    :class:`AidState`: the brake's, then the docking law's."""
    return ((BRAKE_KEYS if aids.brake is not None else ())
            + (DOCKING_KEYS if aids.docking is not None else ()))


def output_specs(aids: AidsConfig, num_envs: int, device: torch.device) -> dict[str, TensorSpec]:
    """The specs of what ``aids`` adds to an env's observation: :func:`output_keys`
    ((N, 1) bool flags, the interventions int64) and, with ``observe_position``,
    ``"position"`` (N, 2) float32 metres."""
    n = num_envs
    specs = {key: Unbounded(shape=(n, 1), dtype=torch.int64, device=device)
             if key == INTERVENTIONS else Binary(n=1, shape=(n, 1), dtype=torch.bool,
                                                  device=device)
             for key in output_keys(aids)}
    if aids.observe_position:
        specs[POSITION] = Unbounded(shape=(n, 2), dtype=torch.float32, device=device)
    return specs


class AidState(NamedTuple):
    """The aids' per-env state, fields (N,): ``braked`` bool, the brake stopped the last step
    of dt; ``interventions`` int64, steps of dt it stopped or steered this episode;
    ``docking_engaged`` bool, the docking law drives this episode; ``docking_reverses`` bool,
    it is reversing."""

    braked: Tensor
    interventions: Tensor
    docking_engaged: Tensor
    docking_reverses: Tensor

    @classmethod
    def zeros(cls, num_envs: int, device: torch.device | str) -> AidState:
        flag = torch.zeros(num_envs, dtype=torch.bool, device=device)
        return cls(flag, torch.zeros(num_envs, dtype=torch.int64, device=device), flag.clone(),
                   flag.clone())


class AidedState(NamedTuple):
    """The paper's state and the aids' beside it."""

    sim: ParkingState
    aids: AidState


class Control(NamedTuple):
    """What the aids make of one action at one state, fields (N,) unless stated: the
    (``speed`` m/s, ``steer`` rad) the car is driven at, and where that step of dt ends
    (``pose`` (N, 3), ``collision``); the aids' next state (``aids``) and whether the brake
    stopped or steered the step (``intervened``)."""

    speed: Tensor
    steer: Tensor
    pose: Tensor
    collision: Tensor
    aids: AidState
    intervened: Tensor


def aided_control(state: AidedState, action: Tensor, world: World, steer_angles: Tensor,
                  cfg: ParkingConfig, aids: AidsConfig) -> Control:
    """One step of dt's control with the aids, without committing it: the docking law may
    replace the clamped action (N, 2), the brake may steer or stop the move. A pure function
    of the state: a teacher's label at any state (``trainers.distill``)."""
    sim, aid = state
    v, delta = clamp_action(action, cfg.vehicle)
    engaged, reverses = aid.docking_engaged, aid.docking_reverses
    if aids.docking is not None:
        v, delta, engaged, reverses = take_over(sim.pose, sim.goal, v, delta, engaged, reverses,
                                                aid.braked, aids.docking, cfg.vehicle)
    pose, collision = move(sim.pose, v, delta, sim.present, world, cfg)
    braked = intervened = torch.zeros_like(collision)
    if aids.brake is not None:
        pose, v, delta, braked, intervened = apply_brake(sim.pose, pose, v, delta, collision,
                                                         sim.present, steer_angles, world, cfg,
                                                         aids.brake.margin)
        collision = torch.zeros_like(collision)
    aid = AidState(braked, aid.interventions + intervened.long(), engaged, reverses)
    return Control(v, delta, pose, collision, aid, intervened)


def aided_step(state: AidedState, action: Tensor, world: World, steer_angles: Tensor,
               cfg: ParkingConfig, aids: AidsConfig, scan: bool = True
               ) -> tuple[AidedState, StepResult, Tensor]:
    """One step of dt with the aids (:func:`aided_control`), committed; the brake's penalty
    joins the paper's reward. ``steer_angles``: the brake's (K,) angles
    (:func:`torchpark.aids.brake.steer_angles`); ``scan``: as
    :func:`~torchpark.sim.step.commit`'s. Returns the new state, what the step emits, and
    whether every action was finite."""
    control = aided_control(state, action, world, steer_angles, cfg, aids)
    sim, out = commit(state.sim, control.pose, control.speed, control.collision, world, cfg,
                      scan)
    if aids.brake is not None:
        out = replace(out, reward=out.reward + torch.where(control.intervened[:, None],
                                                          aids.brake.penalty, 0.0))
    return AidedState(sim, control.aids), out, action.isfinite().all()


def paper_step(state: AidedState, action: Tensor, world: World, cfg: ParkingConfig,
               scan: bool = True) -> tuple[AidedState, StepResult, Tensor]:
    """The paper's step (:func:`~torchpark.sim.step.parking_step`, ``scan`` passed on) on the
    agent's state: the aids' state passes through untouched."""
    sim, out, finite = parking_step(state.sim, action, world, cfg, scan)
    return AidedState(sim, state.aids), out, finite


def agent_observation(state: AidedState, world: World, cfg: ParkingConfig) -> Tensor:
    """The observation (N, NAV_DIM + n_rays) of an agent's state (the paper's,
    :func:`~torchpark.sim.observation.observe`)."""
    return observe(state.sim, world, cfg)[0]


def agent_step(world: World, cfg: ParkingConfig, aids: AidsConfig | None) -> StepFn:
    """The env step an env with ``aids`` runs, ``(state, action) -> (state, out, finite)``:
    :func:`aided_step`, or without aids the paper's own (:func:`paper_step`), held for the
    aids' ``action_repeat`` steps of dt (:func:`~torchpark.aids.repeat.hold`, one function).
    ValueError where the brake's margin does not fit the lot."""
    agent = aids if aids is not None else AidsConfig()
    if aids is None:
        step = partial(paper_step, world=world, cfg=cfg)
    else:
        device = world.goal_poses.device
        if aids.brake is not None:
            check_margin(aids.brake.margin, world, cfg.vehicle)
        angles = (steer_angles(cfg, aids.brake, device) if aids.brake is not None
                  else torch.empty(0, device=device))
        step = partial(aided_step, world=world, steer_angles=angles, cfg=cfg, aids=aids)
    return hold(step, agent.action_repeat, partial(agent_observation, world=world, cfg=cfg))


def drivers(aids: AidsConfig, state: AidState) -> list[str] | None:
    """Which layer drove the last step of each row of ``state``, with the brake or the docking
    law on: "brake" (it stopped the last step of dt), "docking law" (it has taken over), else
    "policy"; None for the paper's env and a policy alone."""
    if not output_keys(aids):
        return None
    return ["brake" if braked else "docking law" if docked else "policy"
            for braked, docked in zip(state.braked.tolist(), state.docking_engaged.tolist(),
                                      strict=True)]


def aided_new_episodes(lots: LotDraw, near: NearDraw | None, world: World, cfg: ParkingConfig
                       ) -> tuple[AidedState, Tensor, Tensor]:
    """The paper's reset of B rows (:func:`~torchpark.sim.step.new_episodes`) with the aids'
    state cleared, and with ``near`` (near-goal starts, B rows) preferred to the uniform
    start where it asks."""
    if near is None:
        fresh, observation, cost = new_episodes(lots, world, cfg)
    else:
        fresh = new_lots(lots, world, cfg)
        fresh = replace(fresh, pose=near_start(fresh.pose, near, fresh.goal, fresh.present,
                                               world, cfg))
        observation, cost = observe(fresh, world, cfg)
    return (AidedState(fresh, AidState.zeros(fresh.pose.shape[0], fresh.pose.device)),
            observation, cost)
