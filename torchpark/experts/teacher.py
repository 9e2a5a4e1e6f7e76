"""The distiller's teacher (:class:`Teacher`): the hand-written expert's control at any state
of a paper's env, composed outside the env, with labels a student can learn from (a function
of the state it sees)."""

from __future__ import annotations

import dataclasses

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from torchpark.aids.brake import steer_angles
from torchpark.aids.config import AidsConfig, BrakeConfig
from torchpark.aids.docking import (
    docking_action,
    docking_phase,
    error_from_goal,
    in_funnel,
    in_settle,
)
from torchpark.aids.step import DOCKING_ENGAGED, INTERVENTIONS, AidedState, AidState, aided_control
from torchpark.config import require
from torchpark.experts.config import TeacherConfig
from torchpark.experts.planner import GearHold, lot_planner, plan_control
from torchpark.sim.state import ParkingState
from torchpark.sim.step import move


class Teacher:
    """The expert of ``config`` (:class:`~torchpark.experts.config.TeacherConfig`) at any
    state of ``env``, a paper's env (no aid acting on the car: the teacher composes its
    own; near-goal starts and an observed position are allowed): the approach
    planner (:mod:`torchpark.experts.planner`) up to its own target, the docking law there,
    the brake under both. The planner's tables take minutes to build at the default grid.

    :meth:`label` returns the (N, 2) control (v m/s, delta rad) the expert would drive with
    at the env's state, and advances the brake's flag as if it had (``intervened``: where
    the brake stopped or steered it). Its labels are a function of what the student sees:
    the law drives wherever the car is in its funnel (not from the moment it entered to the
    episode's end) and in the gear the car moves in (not the pass it began), so a student
    off the teacher's path is not told to reverse where the same pose, moving forwards, is
    told to go on. :meth:`forget` clears the aids' state where episodes ended.

    As a policy (``teacher(td)``, e.g. ``python -m trainers.evaluate --expert teacher``) it
    writes its label into ``td["action"]``, forgetting first the rows whose episode has just
    begun."""

    def __init__(self, config: TeacherConfig, env: EnvBase) -> None:
        base = getattr(env, "base_env", env)
        aids = base.aids
        if aids is not None and (aids.brake is not None or aids.docking is not None
                                 or aids.action_repeat != 1):
            raise ValueError(f"env must step the paper's car (no brake, docking or "
                             f"action_repeat; its starts and observations may differ): the "
                             f"teacher composes its own aids, got {aids}")
        self.config, self.base = config, base
        # the look-ahead tests the one pose reverse_margin m back: no further than the
        # thinnest obstacle, or it could step over one
        thinnest = base.config.lot.thinnest_obstacle
        require(config.reverse_margin <= thinnest, "TeacherConfig.reverse_margin",
                f"in [0, {thinnest:g}] m (LotConfig.thinnest_obstacle, min(wall_thickness, "
                f"car_width))", config.reverse_margin)
        # the law drives in its funnel (planner.law_*); with a look-ahead its own funnel is
        # the planner's target, and the wider one is entered only where the look-ahead is
        # clear
        self.funnel = config.planner.law_funnel(config.docking)
        target = config.planner
        self.law = dataclasses.replace(self.funnel, reach=target.reach, lateral=target.lateral,
                                       heading=target.heading) if config.handover \
            else self.funnel
        self.aids = AidsConfig(docking=self.law, brake=config.brake)
        self.planner = lot_planner(base.config.lot, base.config.vehicle, config.planner,
                                   str(base.device))
        self.angles = steer_angles(base.config, self.aids.brake or BrakeConfig(), base.device)
        self.hold = GearHold(config.planner.gear_hold, base.num_envs, base.device)
        self.state = AidState.zeros(base.num_envs, base.device)
        # (N,) bool: the brake stopped or steered the last label
        self.intervened = torch.zeros(base.num_envs, dtype=torch.bool, device=base.device)

    def ends_short(self, pose: torch.Tensor, reverses: torch.Tensor, present: torch.Tensor
                   ) -> torch.Tensor:
        """Where a reversing pass ends short of contact (``reverse_margin``), bool (n,): the
        rows of ``reverses`` (n,) whose car box at ``pose`` (n, 3), moved that far straight
        back, would touch an obstacle of ``present`` (n, M); none without a margin."""
        margin = self.config.reverse_margin
        if margin == 0:
            return torch.zeros_like(reverses)
        config = self.base.config
        back = torch.full_like(pose[:, 0], -margin / config.vehicle.dt)
        _, near = move(pose, back, torch.zeros_like(back), present, self.base.world, config)
        return reverses & near

    def law_is_clear(self, sim: ParkingState, rows: torch.Tensor) -> torch.Tensor:
        """Whether the law, driving from the cars of ``rows`` (n,) int64 in the gear each
        moves in, goes ``handover`` steps of dt without touching an obstacle, bool (n,)."""
        config, law = self.base.config, self.law
        pose, goal, present = sim.pose[rows], sim.goal[rows], sim.present[rows]
        reverses = sim.speed[rows] < 0
        engaged = torch.ones_like(reverses)
        braked, clear = torch.zeros_like(reverses), torch.ones_like(reverses)
        for _ in range(self.config.handover):
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
        """The expert's control at the env's state, (N, 2) (v m/s, delta rad); the aids'
        state (the brake's flag, the law's phase) advances as if it had driven it."""
        sim, law = self.base.state, self.law
        error = error_from_goal(sim.pose, sim.goal)
        funnel = in_funnel(error, law) | in_settle(error, law)
        if self.config.handover:
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
        """Clear the aids' state of ``rows`` (N,) bool, whose episodes ended."""
        self.state = AidState(*(torch.where(rows, torch.zeros_like(f), f) for f in self.state))

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        """Drive: the label into ``td["action"]``, and beside it the aids' flags the
        evaluator counts (:mod:`torchpark.runner`): the brake's interventions so far in the
        episode and whether the law drove (``interventions``, ``docking_engaged``, (N, 1))."""
        self.forget(self.base.state.steps == 0)
        action = self.label()
        return td.update({"action": action,
                          INTERVENTIONS: self.state.interventions[:, None],
                          DOCKING_ENGAGED: self.state.docking_engaged[:, None]})
