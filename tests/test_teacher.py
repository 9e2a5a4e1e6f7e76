"""The distiller's teacher (torchpark.experts.Teacher): its labels are the expert's control
(the planner, then the docking law in its funnel, with no memory the student cannot see);
its law creeps back, retries, ends reversing passes short of contact and takes over beyond
the target only where its look-ahead is clear; its gear hold follows the car; as a policy it
drives the evaluator's episodes."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import step_mdp

from torchpark import AidsConfig, LotConfig, ParkingConfig, ParkingEnv
from torchpark.aids.config import BrakeConfig, DockingConfig
from torchpark.aids.docking import docking_action, error_from_goal
from torchpark.experts import PlannerConfig, Teacher, TeacherConfig
from torchpark.experts.planner import plan_control
from torchpark.sim.step import move
from trainers.distill.config import COARSE_PLANNER
from trainers.evaluate import evaluate_agent, load_expert


def teacher_on(env, planner: PlannerConfig = COARSE_PLANNER, settle: float = 0.0,
               retry: float = 0.0, **fields) -> Teacher:
    """The teacher of the smoke preset (a coarse planner's tables build in seconds) on
    ``env``, its law creeping back within ``settle`` m and retrying ``retry`` m back,
    ``fields``: TeacherConfig's (reverse_margin, handover)."""
    return Teacher(TeacherConfig(planner=planner, docking=DockingConfig(settle=settle,
                                                                         retry=retry),
                                 brake=BrakeConfig(steer_clear=5), **fields), env)


@pytest.mark.slow
def test_forget_clears_the_aids_state_of_ended_rows():
    paper = ParkingEnv(4, seed=0, config=ParkingConfig(max_steps=200))
    teacher = teacher_on(TransformedEnv(paper), COARSE_PLANNER)
    teacher.state = teacher.state._replace(braked=torch.ones(4, dtype=torch.bool),
                                           docking_engaged=torch.ones(4, dtype=torch.bool))
    teacher.forget(torch.tensor([True, False, True, False]))
    assert teacher.state.braked.tolist() == [False, True, False, True]
    assert teacher.state.docking_engaged.tolist() == [False, True, False, True]


@pytest.mark.slow
def test_the_planner_teacher_drives_the_planner_then_the_law_in_its_target():
    paper = ParkingEnv(16, seed=3, config=ParkingConfig(occupancy=0.9))
    teacher = teacher_on(TransformedEnv(paper), COARSE_PLANNER)
    law = teacher.law
    assert (law.reach, law.lateral, law.heading) == (COARSE_PLANNER.reach, COARSE_PLANNER.lateral,
                                                        COARSE_PLANNER.heading)
    paper.reset()
    sim = paper.state
    label = teacher.label()
    v, delta, _ = plan_control(teacher.planner, sim.pose, sim.speed, sim.goal_slot)
    outside = ~teacher.state.docking_engaged
    assert outside.all()  # uniform starts lie outside the narrowed funnel
    free = ~teacher.intervened
    assert free.any()
    assert torch.equal(label[free], torch.stack((v, delta), -1)[free])
    # lined up 5 m behind each goal: the law drives in
    goal = sim.goal
    back = torch.stack((goal[:, 0] - 5 * torch.cos(goal[:, 2]),
                        goal[:, 1] - 5 * torch.sin(goal[:, 2]), goal[:, 2]), -1)
    teacher.forget(torch.ones(16, dtype=torch.bool))
    paper.set_state(sim._replace(pose=back, speed=torch.zeros(16)))
    label = teacher.label()
    assert teacher.state.docking_engaged.all()
    law_v, law_delta = docking_action(error_from_goal(back, goal),
                                      torch.zeros(16, dtype=torch.bool), law,
                                      paper.config.vehicle)
    free = ~teacher.intervened
    assert torch.equal(label[free], torch.stack((law_v, law_delta), -1)[free])
    # no memory the student cannot see: whatever the aids' state says (the law engaged or
    # not, reversing or not), the label is that of the pose and the speed
    for engaged in (False, True):
        for reverses in (False, True):
            teacher.state = teacher.state._replace(
                docking_engaged=torch.full((16,), engaged),
                docking_reverses=torch.full((16,), reverses),
                braked=torch.zeros(16, dtype=torch.bool))
            assert torch.equal(teacher.label(), label)
    paper.set_state(sim._replace(pose=back, speed=torch.full((16,), -0.5)))
    assert (teacher.label()[free, 0] < 0).all()
    teacher.forget(torch.ones(16, dtype=torch.bool))
    paper.set_state(sim)
    teacher.label()
    assert not teacher.state.docking_engaged.any()  # back at the start: the planner drives


def past_the_goal(side: torch.Tensor) -> ParkingEnv:
    """A paper's env of 16 lots at 90 %, each car 2 mm past its goal, ``side`` (16,) m to
    the left of the slot axis, at 1 mm/s."""
    paper = ParkingEnv(16, seed=3, config=ParkingConfig(occupancy=0.9))
    paper.reset()
    sim = paper.state
    goal = sim.goal
    c, s = torch.cos(goal[:, 2]), torch.sin(goal[:, 2])
    past = torch.stack((goal[:, 0] + 2e-3 * c - side * s, goal[:, 1] + 2e-3 * s + side * c,
                        goal[:, 2]), -1)
    paper.set_state(sim._replace(pose=past, speed=torch.full((16,), 1e-3)))
    return paper


@pytest.mark.slow
def test_with_settle_the_planner_teacher_creeps_back_from_just_past_the_goal():
    paper = past_the_goal(torch.zeros(16))
    speeds = {}
    for settle in (0.0, 0.05):
        teacher = teacher_on(TransformedEnv(paper), COARSE_PLANNER,
                          settle=settle)
        speeds[settle] = teacher.label()[:, 0]
    law = teacher.law
    creep = max(law.speed_gain * 2e-3, law.min_speed)
    torch.testing.assert_close(speeds[0.05], torch.full((16,), -creep), rtol=1e-3, atol=1e-6)
    # without: the planner's pass at full speed, wherever the coarse planner finds a way out
    moving = speeds[0.0] != 0
    assert moving.sum() >= 8 and (speeds[0.0][moving].abs() > 100 * creep).all()


@pytest.mark.slow
def test_with_retry_the_planner_teacher_backs_out_where_the_test_cannot_pass():
    # half the rows 3 mm to the side (a near miss), half 0.1 mm (fine)
    paper = past_the_goal(torch.where(torch.arange(16) % 2 == 0, 3e-3, 1e-4))
    teacher = teacher_on(TransformedEnv(paper), COARSE_PLANNER, settle=0.05,
                      retry=1.0)
    speed = teacher.label()[:, 0]
    law = teacher.law
    assert law.retry == 1.0 and law.settle == 0.05
    creep = max(law.speed_gain * 2e-3, law.min_speed)
    torch.testing.assert_close(speed[1::2], torch.full((8,), -creep), rtol=1e-3, atol=1e-6)
    # the near misses: the law's pass back, at full speed (not the planner's way out of the
    # slot, forwards or backwards wherever its tables say)
    assert (speed[0::2] == -law.max_speed).all()


@pytest.mark.slow
def test_with_a_reverse_margin_the_law_turns_forwards_short_of_contact():
    # cars on their slot's axis 5-6.9 m back, reversing at 1 m/s, at 90 %: the far ones
    # have the lane's other side (a parked car or a wall) close behind
    paper = ParkingEnv(32, seed=3, config=ParkingConfig(occupancy=0.9))
    paper.reset()
    sim = paper.state
    back = torch.linspace(5.0, 6.9, 32)
    goal = sim.goal
    pose = torch.stack((goal[:, 0] - back * torch.cos(goal[:, 2]),
                        goal[:, 1] - back * torch.sin(goal[:, 2]), goal[:, 2]), -1)
    paper.set_state(sim._replace(pose=pose, speed=torch.full((32,), -1.0)))
    speed = {margin: teacher_on(TransformedEnv(paper), COARSE_PLANNER,
                             reverse_margin=margin).label()[:, 0] for margin in (0.0, 0.5)}
    still = torch.zeros(32)
    _, touching = move(pose, still, still, sim.present, paper.world, paper.config)
    _, near = move(pose, torch.full((32,), -0.5 / paper.config.vehicle.dt), still,
                   sim.present, paper.world, paper.config)
    near, free = near & ~touching, ~near & ~touching
    assert near.sum() >= 4 and free.sum() >= 4
    # without the margin the law reverses on (or the brake stops it at contact); with it,
    # the pass ends where 0.5 m more would touch, and nothing changes elsewhere
    assert (speed[0.0][near] <= 0).all() and (speed[0.0][free] < 0).all()
    assert (speed[0.5][near] > 0).all()
    assert torch.equal(speed[0.5][free], speed[0.0][free])


@pytest.mark.slow
@pytest.mark.parametrize(("wall", "margin"), [(1.0, 1.5), (0.75, 0.8), (1.0, float("nan"))])
def test_a_reverse_margin_past_the_lots_thinnest_obstacle_is_refused(wall, margin):
    # the look-ahead tests the one pose that far back: beyond the thinnest obstacle it
    # could step over a wall
    paper = ParkingEnv(2, config=ParkingConfig(lot=LotConfig(wall_thickness=wall)))
    with pytest.raises(ValueError,
                       match=r"^TeacherConfig\.reverse_margin must be (in \[0, |finite)"):
        teacher_on(TransformedEnv(paper), COARSE_PLANNER, reverse_margin=margin)


WIDE_PLAN = dataclasses.replace(COARSE_PLANNER, law_lateral=2.0, law_heading=1.0)


@pytest.mark.slow
def test_with_a_handover_look_ahead_the_law_takes_over_only_where_it_would_touch_nothing():
    # cars 3-7 m behind their goal at 90 %, moving forwards, off the planner's target (0.5 m,
    # 0.25 rad) but in the law's wider funnel (2 m, 1 rad): the law turning in from there
    # touches a parked car within 3 s in some lots, not in others
    n, horizon = 64, 30
    paper = ParkingEnv(n, seed=5, config=ParkingConfig(occupancy=0.9))
    paper.reset()
    sim = paper.state
    generator = torch.Generator().manual_seed(0)
    back, side, turn = torch.rand(3, n, generator=generator)
    back, side = 3.0 + 4.0 * back, torch.where(torch.arange(n) % 2 == 0, 1.0, -1.0)
    lateral, heading = side * (0.6 + 1.2 * turn), -side * 0.9 * turn
    gx, gy, alpha = sim.goal.unbind(-1)
    c, s = torch.cos(alpha), torch.sin(alpha)
    pose = torch.stack((gx - back * c - lateral * s, gy - back * s + lateral * c,
                        alpha + heading), -1)
    _, touching = move(pose, torch.zeros(n), torch.zeros(n), sim.present, paper.world,
                       paper.config)
    paper.set_state(sim._replace(pose=pose, speed=torch.ones(n)))

    def label(plan, handover=0):
        return teacher_on(TransformedEnv(paper), planner=plan,
                       handover=handover).label()

    wide = teacher_on(TransformedEnv(paper), planner=WIDE_PLAN)
    planner_label, law_label = label(COARSE_PLANNER), wide.label()
    looked = label(WIDE_PLAN, horizon)
    # the oracle: the env itself, the law (the wide funnel's, no brake) driving every lot
    lots = ParkingEnv(n, seed=5, config=ParkingConfig(occupancy=0.9),
                      aids=AidsConfig(docking=wide.law))
    lots.reset()
    lots.set_state(paper.state)
    collided = torch.zeros(n, dtype=torch.bool)
    for _ in range(horizon):
        td = lots.step(TensorDict({"action": torch.zeros(n, 2)}, [n]))
        collided |= td["next", "collision"][:, 0]
    clear = ~collided & ~touching
    assert clear.sum() >= 8 and (collided & ~touching).sum() >= 8
    torch.testing.assert_close(looked[clear], law_label[clear])
    torch.testing.assert_close(looked[collided], planner_label[collided])
    # and the two labels differ there: the test can tell them apart
    assert (law_label[collided] != planner_label[collided]).any(-1).sum() >= 4


@pytest.mark.slow
@pytest.mark.parametrize("handover", [-1, 1001, 2.5])
def test_a_handover_out_of_range_is_refused(handover):
    paper = ParkingEnv(2)
    with pytest.raises((ValueError, TypeError), match=r"^TeacherConfig\.handover must be an int"):
        teacher_on(TransformedEnv(paper), planner=WIDE_PLAN, handover=handover)


@pytest.mark.slow
def test_the_teachers_gear_hold_follows_the_car():
    """Labelling states a student drove: every car has just reversed, so the teacher with a
    hold labels what the planner gives when each keeps its gear, where the greedy one
    would turn some of them forwards."""
    paper = ParkingEnv(256, seed=2)
    env = TransformedEnv(paper)
    free = teacher_on(env, COARSE_PLANNER)
    held = teacher_on(env, planner=dataclasses.replace(COARSE_PLANNER, gear_hold=5.0))
    td = env.reset()
    for _ in range(2):  # the student reverses for two steps
        for teacher in (free, held):
            teacher.label()
        td = step_mdp(env.step(td.set("action", torch.tensor([[-2.0, 0.0]]).expand(256, 2))))
    greedy, kept = free.label()[:, 0], held.label()[:, 0]
    planned = ~(free.intervened | held.intervened | free.state.docking_engaged
                | held.state.docking_engaged)  # the planner's labels, not the law's or brake's
    sim = paper.state  # every car has reversed 0.4 m: each keeps reversing where it can
    every = torch.ones(256, dtype=torch.bool)
    keeping = plan_control(held.planner, sim.pose, sim.speed, sim.goal_slot, every)[0]
    assert torch.equal(kept[planned], keeping[planned])
    assert ((greedy > 0) & (kept < 0) & planned).any()  # labels the hold turned back


def test_the_teacher_refuses_an_env_whose_aids_act_on_the_car():
    aided = ParkingEnv(2, aids=AidsConfig(action_repeat=5))
    with pytest.raises(ValueError, match=r"^env must step the paper's car"):
        teacher_on(aided)


@pytest.mark.slow
def test_the_teacher_as_an_expert_drives_the_evaluators_episodes_with_its_labels():
    """``--expert teacher``: the evaluator's row, and its actions the labels a fresh teacher
    gives along the same episodes (each row's state forgotten at its episode's start)."""
    config = TeacherConfig(planner=COARSE_PLANNER, docking=DockingConfig(),
                           brake=BrakeConfig(steer_clear=5))
    agent = load_expert("teacher", config=config)
    assert agent.made_of["agent"] == ("hand-written: approach planner + emergency brake + "
                                      "docking law")
    assert agent.made_of["policy"].startswith("the distiller's teacher")
    [row] = evaluate_agent(agent, 8, levels=[0.9])
    assert row["episodes"] == 8 and 0.0 <= row["success"] <= 1.0
    assert row["docked"] > 0  # the teacher's own law, counted (so is its brake, below)
    env = agent.make_env(0.0, 3, 1)
    policy, check = agent.policy(env), Teacher(config, env)
    td = env.reset()
    for _ in range(30):
        expected = check.label()
        td = policy(td)
        assert torch.equal(td["action"], expected)
        assert torch.equal(td["interventions"][:, 0], check.state.interventions)
        td = step_mdp(env.step(td))
    with pytest.raises(ValueError, match="TeacherConfig"):
        load_expert("teacher", config=PlannerConfig())
