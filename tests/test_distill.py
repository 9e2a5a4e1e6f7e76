"""Distillation (trainers.distill): the final-approach states lie in the law's settled
region and carry its control; the labels in the student's units are what its action map
turns into the teacher's control; a DAgger run writes a checkpoint the evaluator reads as a
policy alone; a resumed run is the run never stopped; the config is one tree, its presets
the committed run's, bad settings refused by their dot names. The teacher itself:
tests/test_teacher.py."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch.utils._pytree import tree_flatten
from torchrl.envs import Compose, TransformedEnv

from tests.test_agent import rows_predict_as_alone
from tests.test_teacher import teacher_on
from torchpark import ParkingConfig, ParkingEnv, SlotGaps
from torchpark.aids.config import DockingConfig
from torchpark.aids.docking import docking_action, error_from_goal
from torchpark.experts import PlannerConfig, TeacherConfig
from torchpark.transforms.actions import PowerActionMap, gear_inverse, power_map_inverse
from torchpark.transforms.features import GoalFrameFeatures
from trainers.agent import load_agent
from trainers.checkpoint import load_checkpoint, load_trained
from trainers.config import env_configs
from trainers.distill import labels
from trainers.distill.cli import main
from trainers.distill.config import PRESETS, DaggerConfig, load_distill_config
from trainers.distill.fit import fit, passes, plan
from trainers.distill.labels import (
    Rollout,
    approach_poses,
    approach_states,
    label_iteration,
    rollout,
    steps_in_stall,
    steps_to_collision,
)
from trainers.distill.loop import BEST_BY
from trainers.evaluate import checkpoint_agent, run_level
from trainers.heads import BinnedGearHead, imitation_error
from trainers.utils import build_models, make_base_env, policy_input

RESULTS = Path(__file__).parent.parent / "results"


def test_the_inverse_power_map_gives_what_the_map_turns_into_the_control():
    high, exponents = torch.tensor([5.0, 0.785]), torch.tensor([3.0, 1.0])
    control = torch.tensor([[1e-3, 0.0], [-2.0, 0.3], [4.9, -0.78], [-1e-4, 1e-4]])
    u = power_map_inverse(control, high, exponents)
    assert (u.abs() < 1).all()
    assert u[0, 0].item() == pytest.approx((1e-3 / 5.0) ** (1 / 3))  # 1 mm/s: 0.058
    td = PowerActionMap(high, exponents).inv(TensorDict({"action": u}, [4]))
    torch.testing.assert_close(td["action"], control, rtol=1e-5, atol=1e-8)


@pytest.mark.slow
def test_approach_poses_lie_in_the_laws_settled_approach_denser_near_the_goal():
    law = DockingConfig()
    goal = torch.tensor([[10.0, 5.0, 1.0], [3.0, -2.0, -2.5]]).repeat(2000, 1)
    error = error_from_goal(approach_poses(goal, 2.0, law, torch.Generator().manual_seed(0)),
                            goal)
    assert ((error.remaining >= -1e-5) & (error.remaining <= 2.0 + 1e-5)).all()  # float32
    assert (error.lateral.abs() <= law.settled_lateral + 1e-5).all()
    assert (error.heading.abs() <= law.settled_heading + 1e-6).all()
    assert error.lateral.min() < 0 < error.lateral.max()
    # u ** 3: the median is an eighth of the bound, a tenth of the states within 2 mm
    assert error.remaining.median().item() == pytest.approx(0.25, rel=0.1)
    assert (error.remaining < 2e-3).float().mean().item() == pytest.approx(0.1, abs=0.02)


@pytest.mark.slow
def test_approach_states_carry_the_laws_forward_control():
    paper = ParkingEnv(64, seed=5, config=ParkingConfig(max_steps=200))
    paper.occupancy = 0.9
    features = GoalFrameFeatures()
    env = TransformedEnv(paper, features)
    teacher = teacher_on(env)
    law = teacher.law
    inputs, labels = approach_states(env, features, teacher, 128, 2.0,
                                     torch.Generator().manual_seed(1))
    assert 0.8 * 128 <= inputs.shape[0] <= 128 and labels.shape == (inputs.shape[0], 2)
    # the law's control at the state each input shows: goal minus pose, the two headings
    dx, dy, cos_psi, sin_psi, v, cos_alpha, sin_alpha = inputs[:, :7].unbind(-1)
    zero = torch.zeros_like(dx)
    error = error_from_goal(torch.stack([zero, zero, torch.atan2(sin_psi, cos_psi)], -1),
                            torch.stack([dx, dy, torch.atan2(sin_alpha, cos_alpha)], -1))
    assert (error.lateral.abs() <= law.settled_lateral + 1e-5).all()
    speed = labels[:, 0]
    assert (speed > 0).all()  # driving in, never reversing
    assert ((v >= 0) & (v <= 2 * speed + 1e-7)).all()  # what it came in with, up to twice
    law_v, law_delta = docking_action(error, torch.zeros_like(dx, dtype=torch.bool), law,
                                      paper.config.vehicle)
    same = (labels - torch.stack([law_v, law_delta], -1)).abs().amax(-1) < 1e-4
    assert same.float().mean() > 0.9  # the law's control, unless the brake steered


@pytest.mark.parametrize("override, name", [
    ("dagger.iterations=0", "dagger.iterations"), ("dagger.iterations=true", "dagger.iterations"),
    ("student.env.num_envs=1.5", "student.env.num_envs"),
    ("student.env.num_envs=0", "student.env.num_envs"),
    ("student.agent.aids.near_goal_starts.probability=2.0",
     "student.agent.aids.near_goal_starts.probability"),
    ("dagger.noise=nan", "dagger.noise"), ("dagger.replay=-1.0", "dagger.replay"),
    ("dagger.replay=nan", "dagger.replay"), ("dagger.lr=-1.0", "dagger.lr"),
    ("dagger.approach=-1", "dagger.approach"), ("dagger.approach=0.5", "dagger.approach"),
    ("dagger.approach_weight=0.0", "dagger.approach_weight"),
    ("dagger.collision_weight=0.0", "dagger.collision_weight"),
    ("dagger.collision_weight=inf", "dagger.collision_weight"),
    ("dagger.collision_horizon=0", "dagger.collision_horizon"),
    ("dagger.stall_from=0", "dagger.stall_from"), ("dagger.stall_from=1.5", "dagger.stall_from"),
    ("student.agent.action_exponents=[0.5,1.0]", "student.agent.action_exponents"),
    ("student.agent.action_exponents=[3.0,inf]", "student.agent.action_exponents"),
    ("dagger.dagger_epochs=0", "dagger.dagger_epochs"), ("dagger.lr_decay=1", "dagger.lr_decay"),
    ("dagger.final_epochs=-1", "dagger.final_epochs"),
    ("teacher.docking.settle=-0.01", "teacher.docking.settle"),
    ("teacher.docking.settle=nan", "teacher.docking.settle"),
    ("teacher.docking.retry=-1.0", "teacher.docking.retry"),
    ("teacher.docking.retry=inf", "teacher.docking.retry"),
    ("teacher.reverse_margin=-0.5", "teacher.reverse_margin"),
    ("teacher.reverse_margin=nan", "teacher.reverse_margin"),
    ("teacher.planner.gear_hold=-0.5", "teacher.planner.gear_hold"),
    ("teacher.planner.gear_hold=nan", "teacher.planner.gear_hold"),
    ("teacher.planner.lateral=0.0", "teacher.planner.lateral"),
    ("teacher.planner.lateral=inf", "teacher.planner.lateral"),
    ("teacher.planner.heading=-0.1", "teacher.planner.heading"),
    ("teacher.planner.heading=4.0", "teacher.planner.heading"),
    ("teacher.planner.law_lateral=0.0", "teacher.planner.law_lateral"),
    ("teacher.planner.law_lateral=0.1", "teacher.planner.law_lateral"),  # inside the target
    ("teacher.planner.law_heading=4.0", "teacher.planner.law_heading"),
    ("teacher.planner.law_heading=0.1", "teacher.planner.law_heading"),
    ("teacher.planner.headings=7", "teacher.planner.headings"),
    ("teacher.planner.headings=2000", "teacher.planner.headings"),
    ("teacher.handover=-1", "teacher.handover"), ("teacher.handover=1001", "teacher.handover"),
    ("teacher.handover=2.5", "teacher.handover"),
    ("student.model.steer_bins=4", "student.model.steer_bins"),
    ("student.model.steer_bins=1", "student.model.steer_bins"),
    ("student.model.steer_bins=257", "student.model.steer_bins"),
    ("student.model.hidden=[]", "student.model.hidden"),
    ("student.model.hidden=[0]", "student.model.hidden"),
    ("student.model.hidden=[true]", "student.model.hidden"),
    ("student.agent.features=[slots]", "student.agent.features"),  # without position
    ("student.agent.features=[goal,brake]", "student.agent.features"),  # no brake
    ("student.agent.gear_head=false", "student.agent.gear_head"),
    ("student.agent.aids.action_repeat=5", "student.agent.aids"),
    ("student.agent.aids.docking={}", "student.agent.aids"),
    ("student.env.device=meta", "student.env.device"),
    ("dagger.hazard_weight=1.0", "dagger.hazard_weight"),  # no such field
    ("seed=-1", "seed")])
def test_bad_settings_are_refused_by_their_dot_names(override, name):
    with pytest.raises(ValueError, match=rf"^{name}\b"):
        load_distill_config("smoke", [override])


def test_the_command_line_names_the_field_of_a_funnel_inside_the_target(capsys):
    with pytest.raises(SystemExit) as refused:
        main(["--out", "student", "teacher.planner.law_lateral=0.1"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert refused.value.code == 2
    assert "teacher.planner.law_lateral (PlannerConfig.law_lateral) must be" in err, err
    assert "[lateral = 0.25, inf]" in err


def test_the_help_lists_every_field_with_the_presets_value(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    for line in ("teacher.planner.headings = 96", "teacher.handover = 50",
                 "student.model.hidden = [512, 512, 512]", "dagger.iterations = 22",
                 "student.agent.memory_scans = 3", "seed = 1",
                 "student.agent.features = ['goal', 'clearance', 'gear', 'scan_memory', "
                 "'slots', 'position']"):
        assert f"  {line}\n" in out


@pytest.mark.slow
def test_the_policy_alone_preset_is_the_committed_runs_config():
    """Field by field: the student the committed checkpoint holds; the teacher the distiller
    before its config tree built from ``results/fast/checkpoint_final.pt``'s law and brake
    with the committed command's flags; DAgger's schedule those flags over its defaults."""
    cfg = PRESETS["policy_alone"]()
    committed = load_checkpoint(RESULTS / "policy_alone" / "checkpoint_best.pt")
    assert dataclasses.asdict(cfg.student_run()) == committed["config"]
    fast, _ = load_trained(str(RESULTS / "fast" / "checkpoint_final.pt"))
    _, aids = env_configs(fast, training=False)
    assert cfg.teacher == TeacherConfig(
        planner=PlannerConfig(headings=96, lateral=0.25, heading=0.12, law_lateral=0.6,
                              law_heading=0.55, gear_hold=0.75, car_margin=0.2),
        docking=dataclasses.replace(aids.docking, settle=0.05, retry=1.0), brake=aids.brake,
        reverse_margin=0.5, handover=50)
    assert dataclasses.asdict(cfg.dagger) == {
        "iterations": 22, "steps": 400, "noise": 0.05, "approach": 32768,
        "approach_reach": 2.0, "approach_weight": 10.0, "collision_weight": 10.0,
        "collision_horizon": 10, "stall_weight": 5.0, "stall_from": 10, "epochs": 32,
        "dagger_epochs": 8, "batch_size": 1024, "lr": 1e-3, "lr_decay": True,
        "replay": 0.0, "final_epochs": 0, "yardstick": 200}
    assert cfg.seed == 1


@pytest.mark.slow
def test_a_run_writes_a_policy_alone_the_evaluator_reads(tmp_path, capsys):
    out = tmp_path / "student"
    args = ["--preset", "smoke", "--out", str(out), "dagger.iterations=2", "student.env.num_envs=8",
            "dagger.steps=20", "dagger.epochs=1", "dagger.dagger_epochs=1", "dagger.yardstick=4",
            "dagger.approach=16"]
    main(args)
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert cfg.agent.aids.brake is None and cfg.agent.aids.docking is None
    assert cfg.agent.aids.action_repeat == 1 and cfg.agent.action_exponents == [3.0, 1.0]
    assert cfg.agent.gear_head
    made_of = checkpoint_agent(str(out / "checkpoint_final.pt")).made_of
    assert made_of["agent"] == "policy alone"
    assert made_of["policy"].startswith("distilled (gear head, features goal) from the "
                                         "approach planner")
    assert checkpoint["frames"] == 2 * 6 * 20 * 8
    agent = load_agent(str(out / "checkpoint_final.pt"))
    env = agent.make_env(4, 0.9, seed=0)
    assert env.action_spec.shape == (4, 5)
    env.rollout(3, agent.policy)
    rows = (out / "dagger.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[0].startswith("iteration,frames,approach_states")
    # checkpoint_best.pt: the iteration that scored best on the checks (the later on a tie)
    checks = list(csv.DictReader(rows))
    scores = [sum(float(r[key]) for key in BEST_BY) for r in checks]
    best = max(i for i, s in enumerate(scores) if s == max(scores))
    _, best_checkpoint = load_trained(str(out / "checkpoint_best.pt"))
    assert f": {best + 1} iteration(s)" in best_checkpoint["trained_by"]
    # the final approach is labelled in the first iteration only
    assert 0.8 * 6 * 16 <= int(rows[1].split(",")[2]) == int(rows[2].split(",")[2]) <= 6 * 16
    with pytest.raises(SystemExit):
        main(args)  # the checkpoint exists: refused without --overwrite
    assert "--overwrite" in capsys.readouterr().err
    (out / "checkpoint_final.pt").unlink()
    with pytest.raises(SystemExit):
        main(args)  # any of its outputs (here the best checkpoint, the log, the state) is kept
    assert "checkpoint_best.pt exists (3 of the outputs do)" in capsys.readouterr().err


@pytest.mark.slow
def test_a_student_with_the_clearance_features_and_position_reads_them_everywhere(tmp_path):
    """The rays' clearance and the car's position join the student's input in its rollouts,
    its final-approach states and the evaluator's env alike."""
    out = tmp_path / "clearance"
    main(["--preset", "smoke", "--out", str(out), "dagger.iterations=1", "student.env.num_envs=4",
          "dagger.steps=5", "dagger.epochs=1", "dagger.yardstick=2", "dagger.approach=8",
          "student.agent.features=[goal,clearance,position]",
          "student.agent.aids.observe_position=true"])
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert cfg.agent.features == ["goal", "clearance", "position"]
    assert cfg.agent.aids.observe_position
    assert checkpoint["trained_by"].startswith(
        "distilled (gear head, features goal/clearance/position) from")
    loc = checkpoint["obs_norm"]["_extra_state"]["loc.-|-.observation_policy"]
    assert loc.shape[-1] == 23 + 7 + 16 + 2
    agent = load_agent(str(out / "checkpoint_final.pt"))
    agent.make_env(2, 0.9, seed=0).rollout(3, agent.policy)


@pytest.mark.slow
def test_a_student_with_the_gear_features_reads_them_everywhere(tmp_path):
    """The gear and its travel join the student's input (after the clearance, before the
    position) in its rollouts, its final-approach states and the evaluator's env alike."""
    out = tmp_path / "gear"
    main(["--preset", "smoke", "--out", str(out), "dagger.iterations=2", "student.env.num_envs=4",
          "dagger.steps=5", "dagger.epochs=1", "dagger.dagger_epochs=1", "dagger.yardstick=2",
          "dagger.approach=8", "student.agent.features=[goal,clearance,gear,position]",
          "student.agent.aids.observe_position=true", "teacher.planner.gear_hold=0.5"])
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert "gear" in cfg.agent.features
    assert checkpoint["trained_by"].startswith(
        "distilled (gear head, features goal/clearance/gear/position) from")
    data = torch.load(out / "dagger_data" / "iteration_001.pt")
    assert data[0].shape[-1] == 23 + 7 + 16 + 2 + 2
    gear, travel = data[0][:, -4], data[0][:, -3]
    assert set(gear.unique().tolist()) <= {-1.0, 0.0, 1.0}
    assert bool(((travel >= 0) & (travel <= 1)).all()) and bool((travel < 1).any())
    agent = load_agent(str(out / "checkpoint_final.pt"))
    agent.make_env(2, 0.9, seed=0).rollout(3, agent.policy)


@pytest.mark.slow
def test_a_student_with_a_scan_memory_reads_it_everywhere_and_predicts_with_it(tmp_path):
    """The scan memory joins the student's input (after the gear features, before the
    position) in its rollouts and its final-approach states; its Gymnasium ``predict``
    carries the memory as a recurrent state and drives the evaluator's episode to the last
    bit, and a batch's row flagged as a new episode's start forgets it."""
    out = tmp_path / "memory"
    main(["--preset", "smoke", "--out", str(out), "dagger.iterations=2", "student.env.num_envs=4",
          "dagger.steps=5", "dagger.epochs=1", "dagger.dagger_epochs=1", "dagger.yardstick=2",
          "dagger.approach=8",
          "student.agent.features=[goal,clearance,gear,scan_memory,position]",
          "student.agent.aids.observe_position=true", "student.agent.memory_scans=2"])
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert cfg.agent.memory_scans == 2
    assert checkpoint["trained_by"].startswith(
        "distilled (gear head, features goal/clearance/gear/scan_memory/position, a memory "
        "of 2 scans)")
    data = torch.load(out / "dagger_data" / "iteration_001.pt")
    assert data[0].shape[-1] == 23 + 7 + 16 + 2 + 16 + 2
    path = str(out / "checkpoint_final.pt")
    evaluated = run_level(checkpoint_agent(path), 0.6, episodes=1, seed=5)
    agent = load_agent(path)
    env = agent.gym_env(occupancy=0.6, seed=5)
    obs, info = env.reset()
    poses, states, state = [env.unwrapped.env.state.pose[0].clone()], [], None
    for _ in range(int(evaluated.length[0])):
        action, state = agent.predict(obs, info, state=state)
        states.append((obs, info, state))
        obs, _r, terminated, truncated, info = env.step(action)
        poses.append(env.unwrapped.env.state.pose[0].clone())
    assert terminated or truncated
    torch.testing.assert_close(torch.stack(poses), evaluated.poses[:len(poses), 0], rtol=0,
                               atol=0)
    assert state.shape == (2 + 2 * (4 + 16),)
    (_obs, _info, before), (after_obs, after_info, _) = states[3], states[4]
    going_on, fresh = rows_predict_as_alone(agent, after_obs, after_obs, after_info, before)
    assert not np.array_equal(going_on[1][2:], fresh[1][2:])  # the memory went on
    with pytest.raises(ValueError, match=r"state must be the \(42,\)"):
        agent.predict(after_obs, after_info, state=before[:2])


@pytest.mark.slow
def test_a_student_with_the_slot_features_reads_them_everywhere(tmp_path):
    """The slots' gaps join the student's input (before the position) in its rollouts and
    its final-approach states, each row's the features of its own observation and position;
    its Gymnasium ``predict`` reads the position from ``info`` and drives the evaluator's
    episode to the last bit."""
    out = tmp_path / "slots"
    main(["--preset", "smoke", "--out", str(out), "dagger.iterations=2", "student.env.num_envs=4",
          "dagger.steps=5", "dagger.epochs=1", "dagger.dagger_epochs=1", "dagger.yardstick=2",
          "dagger.approach=8", "student.agent.aids.observe_position=true",
          "student.agent.features=[goal,slots,position]"])
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert "slots" in cfg.agent.features
    assert checkpoint["trained_by"].startswith("distilled (gear head, features "
                                               "goal/slots/position) from")
    for iteration in (0, 1):  # iteration 0 holds the final-approach states
        inputs = torch.load(out / "dagger_data" / f"iteration_{iteration:03d}.pt")[0]
        assert inputs.shape[-1] == 23 + 7 + 16 + 2
        gaps = SlotGaps(cfg.env.task)(TensorDict({"observation": inputs[:, :23],
                                                  "position": inputs[:, -2:]},
                                                 [inputs.shape[0]]))
        assert torch.equal(gaps["observation_policy"][:, 23:], inputs[:, 30:46])
    path = str(out / "checkpoint_final.pt")
    evaluated = run_level(checkpoint_agent(path), 0.6, episodes=1, seed=5)
    agent = load_agent(path)
    env = agent.gym_env(occupancy=0.6, seed=5)
    obs, info = env.reset()
    poses, state = [env.unwrapped.env.state.pose[0].clone()], None
    for _ in range(int(evaluated.length[0])):
        action, state = agent.predict(obs, info, state=state)
        obs, _r, terminated, truncated, info = env.step(action)
        poses.append(env.unwrapped.env.state.pose[0].clone())
    assert terminated or truncated
    torch.testing.assert_close(torch.stack(poses), evaluated.poses[:len(poses), 0], rtol=0,
                               atol=0)


@pytest.mark.slow
def test_a_student_with_binned_steering_is_fitted_and_driven_by_its_bins(tmp_path):
    out = tmp_path / "bins"
    main(["--preset", "smoke", "--out", str(out), "dagger.iterations=2", "student.env.num_envs=4",
          "dagger.steps=5", "dagger.epochs=1", "dagger.dagger_epochs=1", "dagger.yardstick=2",
          "dagger.approach=8", "student.model.steer_bins=5", "dagger.collision_weight=4",
          "dagger.collision_horizon=3"])
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert cfg.model.steer_bins == 5
    assert checkpoint["trained_by"].startswith(
        "distilled (gear head, features goal, binned steering) from")
    assert ("2 iteration(s) (DAgger after the first; the states up to 3 steps before its own "
            "collisions weighted 4)") in checkpoint["trained_by"]
    agent = load_agent(str(out / "checkpoint_final.pt"))
    head = agent.actor.module[0].module[0]
    assert isinstance(head, BinnedGearHead) and head.bins == 5
    td = agent.make_env(2, 0.9, seed=0).rollout(3, agent.policy)
    assert torch.allclose(td["action"], head.action(td["observation_norm"]), atol=1e-5)


def test_steps_to_collision_count_back_from_the_colliding_step_within_its_episode():
    # Row 0 collides at step 2 and starts a new episode that runs past the end; row 1's
    # first episode ends at step 1 without a collision, its second collides at step 4.
    collided = torch.tensor([[0, 0], [0, 0], [1, 0], [0, 0], [0, 1]], dtype=torch.bool)
    done = torch.tensor([[0, 0], [0, 1], [1, 0], [0, 0], [0, 1]], dtype=torch.bool)
    inf = float("inf")
    assert torch.equal(steps_to_collision(collided, done),
                       torch.tensor([[3, inf], [2, inf], [1, 3], [inf, 2], [inf, 1]]))


def test_a_stall_is_a_window_of_one_episode_that_ends_near_where_it_began():
    # Row 0 rocks 0.4 m forwards and back; row 1 drives 0.5 m a step; row 2 rocks but its
    # episode ends at step 3 (its next one starts where it stood); row 3 stands still (no
    # stall: the docking law's creep to the goal looks so); row 4 rocks and its episode
    # ends at step 5 (rocking that ends in a park or a collision is no stall).
    steps = 6
    t = torch.arange(steps + 1, dtype=torch.float32)
    x = torch.stack((0.4 * (t % 2), 0.5 * t, 0.4 * (t % 2), torch.zeros_like(t),
                     0.4 * (t % 2)), -1)
    positions = torch.stack((x, torch.zeros_like(x)), -1)  # (T + 1, N, 2)
    goals = torch.tensor([10.0, 0.0]).expand(steps, 5, 2).clone()
    done = torch.zeros(steps, 5, dtype=torch.bool)
    done[3, 2] = done[5, 4] = True
    stalled = steps_in_stall(positions, goals, done, window=3, distance=1.0, travel=1.0)
    expected = torch.zeros(steps, 5, dtype=torch.bool)
    expected[:4, 0] = True  # windows from states 0-3 cover 1.2 m and end within 0.4 m
    # row 2: its first episode ends within the rollout, no window fits in its second
    assert torch.equal(stalled, expected)
    assert torch.equal(steps_in_stall(positions, goals, done, window=3, distance=1.0, travel=1.3),
                       torch.zeros(steps, 5, dtype=torch.bool))  # rocking, but not that far
    assert not steps_in_stall(positions, goals, done, window=7, travel=0.0).any()  # past the end
    goals[2:, 0, 0] = 0.5  # near the goal from state 2 on: lining up, not stalling
    expected[2:, 0] = False
    assert torch.equal(steps_in_stall(positions, goals, done, window=3, travel=1.0), expected)


@pytest.mark.slow
def test_a_rollout_counts_the_steps_to_the_drivers_collisions():
    # A driver that floors it forwards, turning a little, at 90 %: into the parked cars.
    scfg = PRESETS["smoke"]().student_run()
    base = make_base_env(scfg, training=True, num_envs=8, seed=0)
    base.occupancy = 0.9
    inputs = policy_input(scfg, base)
    env = TransformedEnv(base, Compose(*inputs))
    teacher = teacher_on(env)
    floor_it = torch.tensor([1.0, 1.0, 0.3, 1.0, 0.0])  # gear, (speed, steer) per gear

    def driver(td):
        return td.set("action", floor_it.expand(td.shape[0], 5))

    steps = 40
    r = rollout(env, driver, teacher, torch.tensor([3.0, 1.0]), steps, False, 0.0,
                torch.Generator().manual_seed(0))
    assert all(t.shape[0] == steps * 8 for t in r)
    assert not r.stalled.any()  # 40 steps: no 100-step window fits
    ahead = r.ahead.reshape(steps, 8)
    assert (ahead == 1).sum() >= 4  # collisions
    # Within a row the count runs down by one a step to the colliding step's 1.
    before = ahead[:-1].isfinite() & (ahead[:-1] > 1)
    assert torch.equal(ahead[1:][before], ahead[:-1][before] - 1)


def test_a_states_weight_is_the_product_of_its_collision_and_stall_weights(
        monkeypatch):
    inf = float("inf")
    states = Rollout(
        inputs=torch.zeros(5, 3), labels=torch.zeros(5, 2),
        ahead=torch.tensor([1.0, inf, inf, 3.0, inf]),
        stalled=torch.tensor([False, True, False, True, True]))
    monkeypatch.setattr(labels, "rollout", lambda *args: states)
    base = SimpleNamespace(action_spec=SimpleNamespace(space=SimpleNamespace(
        high=torch.ones(1, 2))), occupancy=0.0)
    cfg = DaggerConfig(approach=0, collision_weight=3.0, collision_horizon=2, stall_weight=5.0,
                       stall_from=1)
    env = SimpleNamespace(base_env=base, transform=[SimpleNamespace(freeze=lambda: None)])
    (x, y, w), frames, approach = label_iteration(
        env, None, None, None, torch.ones(2), cfg, 1, torch.Generator(), False)
    # a collision 1 step ahead; a stall; neither; a stall 3 steps before a collision beyond
    # the horizon; a stall
    assert torch.equal(w, torch.tensor([3.0, 5.0, 1.0, 5.0, 5.0]).repeat(6))
    cfg.collision_horizon = 3  # both hold at the 4th state: the weights multiply
    (_, _, w), _, _ = label_iteration(env, None, None, None, torch.ones(2), cfg, 1,
                                      torch.Generator(), False)
    assert torch.equal(w[:5], torch.tensor([3.0, 5.0, 1.0, 15.0, 5.0]))
    (_, _, w), _, _ = label_iteration(env, None, None, None, torch.ones(2), cfg, 0,
                                      torch.Generator(), False)
    assert torch.equal(w[:5], torch.tensor([3.0, 1.0, 1.0, 3.0, 1.0]))  # stalls from 1 on
    assert frames == 30 and approach == 0 and x.shape == (30, 3) and y.shape == (30, 2)


def test_a_gear_head_is_scored_on_its_gear_and_that_gears_pair_only():
    label = torch.tensor([[0.6, -0.2], [-0.4, 0.5], [0.0, 0.1]])
    exact = gear_inverse(label)
    assert torch.equal(imitation_error(exact, label), torch.zeros(3))
    other = exact.clone()
    other[0, 3:], other[1, 1:3] = torch.tensor([0.9, 0.9]), torch.tensor([-0.7, 0.3])
    assert torch.equal(imitation_error(other, label), torch.zeros(3))  # the unused pairs
    wrong = exact.clone()
    wrong[:, 0] = -wrong[:, 0]
    assert torch.allclose(imitation_error(wrong, label), torch.full((3,), 4.0))


@pytest.mark.slow
def test_the_students_layers_are_its_model_sections():
    cfg = load_distill_config("smoke", ["student.model.hidden=[24,24,24]"])
    actor, _ = build_models(cfg.student_run())
    linears = [m for m in actor.modules() if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in linears[:-1]] == [24] * 3


@pytest.mark.parametrize(("final_epochs", "last"), [(0, (3, 0.5)), (7, (7, 0.0))])
def test_a_closing_refit_makes_the_last_fit_passes_over_the_whole_aggregate(final_epochs, last):
    cfg = DaggerConfig(iterations=4, epochs=5, dagger_epochs=3, replay=0.5,
                       final_epochs=final_epochs)
    assert [plan(cfg, k) for k in range(4)] == [(5, 0.5), (3, 0.5), (3, 0.5), last]
    # a single iteration is the first and the last: the closing refit wins
    one = dataclasses.replace(cfg, iterations=1)
    assert plan(one, 0) == ((7, 0.0) if final_epochs else (5, 0.5))


def test_the_full_refit_passes_over_every_state_in_a_fresh_order():
    order, scale = passes(10, 4, 3, 0.0, torch.Generator().manual_seed(0), kept=(2, 5))
    assert torch.equal(scale, torch.ones(10)) and len(order) == 3
    assert all(torch.equal(o.sort().values, torch.arange(10)) for o in order)
    assert not torch.equal(order[0], order[1])


@pytest.mark.parametrize(("total", "new", "replay", "kept", "drawn"),
                         [(1000, 100, 1.0, (0, 0), 100), (1000, 100, 0.5, (0, 0), 50),
                          (150, 100, 2.0, (0, 0), 50), (1000, 100, 1.0, (300, 500), 100),
                          (250, 100, 2.0, (100, 150), 100)])
def test_a_replayed_pass_holds_the_new_and_kept_states_and_a_weighted_draw_of_the_rest(
        total, new, replay, kept, drawn):
    order, scale = passes(total, new, 4, replay, torch.Generator().manual_seed(0), kept)
    earlier_count = total - new
    held = torch.arange(*kept)
    is_other = torch.ones(total, dtype=torch.bool)
    is_other[held], is_other[earlier_count:] = False, False
    others = int(is_other.sum())
    assert torch.equal(scale, torch.where(is_other, others / drawn, 1.0))
    for o in order:
        # a pass's work: bounded, whatever the aggregate
        assert o.shape[0] == new + held.shape[0] + drawn
        kept_or_new = o[~is_other[o]].sort().values  # every new and kept state, once
        assert torch.equal(kept_or_new, torch.cat((held, torch.arange(earlier_count, total))))
        old = o[is_other[o]]
        assert old.unique().shape[0] == drawn  # drawn without replacement
        # the weights stand for the whole aggregate: a pass's total weight is its size
        assert scale[o].sum().item() == pytest.approx(total)
    if drawn < others:  # a fresh draw each pass (else each draws all of them)
        assert not torch.equal(order[0][is_other[order[0]]].sort().values,
                               order[1][is_other[order[1]]].sort().values)
    # the first iteration, or no replay: the full refit
    assert torch.equal(passes(total, total, 2, replay, torch.Generator())[1], torch.ones(total))


@pytest.mark.slow
@pytest.mark.parametrize("lr_decay", [False, True])
def test_each_fit_starts_at_lr_and_decays_to_zero_if_asked(lr_decay):
    cfg = DaggerConfig(lr=1e-3, lr_decay=lr_decay, batch_size=16)
    scfg = PRESETS["smoke"]().student_run()
    base = make_base_env(scfg, training=True, num_envs=4, seed=0)
    inputs = policy_input(scfg, base)
    TransformedEnv(base, Compose(*inputs)).rollout(3)
    norm = inputs[-1]
    norm.freeze()
    actor, _ = build_models(scfg)
    optim = torch.optim.Adam(actor.parameters(), lr=cfg.lr)
    generator = torch.Generator().manual_seed(0)
    x, y = torch.randn(64, 30, generator=generator), torch.rand(64, 2, generator=generator)
    for _ in range(2):  # the second fit starts from lr again: it moves the weights
        before = [p.clone() for p in actor.parameters()]
        order, _ = passes(64, 64, 3, 0.0, generator)
        fit(actor, norm.to_observation_norm(), x, y, torch.ones(64), order, cfg, optim)
        assert any(not torch.equal(a, b) for a, b in zip(before, actor.parameters(), strict=True))
        lr = optim.param_groups[0]["lr"]
        assert lr == (pytest.approx(0.0, abs=1e-12) if lr_decay else cfg.lr)


@pytest.mark.slow
def test_a_resumed_run_gives_the_checkpoints_of_a_run_never_stopped(tmp_path,
                                                                    capsys):
    flags = ["student.env.num_envs=8", "dagger.steps=12", "dagger.epochs=2",
             "dagger.dagger_epochs=1", "dagger.yardstick=4", "dagger.approach=16",
             "student.agent.aids.observe_position=true",
             "student.agent.features=[goal,position]", "student.model.steer_bins=5"]
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    main(["--preset", "smoke", "--out", str(whole), "dagger.iterations=3", *flags])
    main(["--preset", "smoke", "--out", str(parts), "dagger.iterations=1", *flags])
    main(["--preset", "smoke", "--out", str(parts), "dagger.iterations=3", "--resume", *flags])
    assert "resumed after iteration 1 of 3" in capsys.readouterr().out
    for name in ("checkpoint_final.pt", "checkpoint_best.pt"):
        a, b = (torch.load(d / name, weights_only=True) for d in (whole, parts))
        assert a["trained_by"] == b["trained_by"] and a["frames"] == b["frames"]
        for key in ("actor", "obs_norm"):
            leaves, spec = tree_flatten(a[key])
            theirs, their_spec = tree_flatten(b[key])
            assert spec == their_spec
            assert all(torch.equal(x, y) if isinstance(x, torch.Tensor) else x == y
                       for x, y in zip(leaves, theirs, strict=True))

    def table(d):  # the wall-clock aside
        return [{k: v for k, v in r.items() if k != "wall_s"}
                for r in csv.DictReader((d / "dagger.csv").read_text().splitlines())]
    assert table(whole) == table(parts) and len(table(parts)) == 3


@pytest.mark.slow
def test_resuming_refuses_what_would_not_continue_the_run(tmp_path, capsys):
    """Each refusal names what is wrong and leaves the run's state as it was (one run for
    the three: each refused command changes nothing, the test checks)."""
    flags = ["student.env.num_envs=4", "dagger.steps=4", "dagger.epochs=1",
             "dagger.dagger_epochs=1", "dagger.yardstick=2", "dagger.approach=0"]
    out = tmp_path / "run"
    main(["--preset", "smoke", "--out", str(out), "dagger.iterations=2", *flags])
    capsys.readouterr()
    before = (out / "dagger_state.pt").read_bytes()
    for change, error in (
            (["dagger.iterations=1", "--resume"], "dagger.iterations must be >= 2"),
            (["dagger.iterations=3", "--resume", "dagger.lr=0.01"],
             "has dagger.lr=0.001, this command dagger.lr=0.01"),
            (["dagger.iterations=3", "--resume", "--overwrite"], "pass one of them")):
        with pytest.raises(SystemExit):
            main(["--preset", "smoke", "--out", str(out), *flags, *change])
        assert error in capsys.readouterr().err
        assert (out / "dagger_state.pt").read_bytes() == before


@pytest.mark.slow
def test_a_run_saved_before_a_setting_existed_resumes_at_its_default(tmp_path,
                                                                    capsys):
    flags = ["student.env.num_envs=4", "dagger.steps=4", "dagger.epochs=1",
             "dagger.dagger_epochs=1", "dagger.yardstick=2", "dagger.approach=0"]
    out = tmp_path / "run"
    main(["--preset", "smoke", "--out", str(out), "dagger.iterations=1", *flags])
    state = torch.load(out / "dagger_state.pt", weights_only=True)
    del state["distill"]["teacher"]["planner"]["gear_hold"]  # saved before it existed
    torch.save(state, out / "dagger_state.pt")
    main(["--preset", "smoke", "--out", str(out), "dagger.iterations=2", "--resume", *flags])
    assert "resumed after iteration 1 of 2" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--preset", "smoke", "--out", str(out), "dagger.iterations=3", "--resume",
              "teacher.planner.gear_hold=0.5", *flags])
    assert ("has teacher.planner.gear_hold=0.0, this command "
            "teacher.planner.gear_hold=0.5") in capsys.readouterr().err
    # a setting this distiller has dropped since the run was saved is refused by name
    state = torch.load(out / "dagger_state.pt", weights_only=True)
    state["distill"]["dagger"]["hazard_weight"] = 0.1
    torch.save(state, out / "dagger_state.pt")
    before = (out / "dagger_state.pt").read_bytes()
    with pytest.raises(SystemExit):
        main(["--preset", "smoke", "--out", str(out), "dagger.iterations=3", "--resume", *flags])
    assert ("has dagger.hazard_weight=0.1, a setting this distiller no longer has"
            in capsys.readouterr().err)
    assert (out / "dagger_state.pt").read_bytes() == before


@pytest.mark.slow
def test_resuming_refuses_another_teacher_or_no_run(tmp_path, capsys):
    flags = ["student.env.num_envs=4", "dagger.steps=4", "dagger.epochs=1",
             "dagger.dagger_epochs=1", "dagger.yardstick=2", "dagger.approach=0",
             "dagger.iterations=2"]
    with pytest.raises(SystemExit):
        main(["--preset", "smoke", "--out", str(tmp_path / "empty"), "--resume", *flags])
    assert "dagger_state.pt does not exist" in capsys.readouterr().err
    out = tmp_path / "run"
    main(["--preset", "smoke", "--out", str(out), *flags[:-1], "dagger.iterations=1"])
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["--preset", "smoke", "--out", str(out), "--resume", *flags, "teacher.handover=5"])
    assert "has teacher.handover=0, this command teacher.handover=5" in capsys.readouterr().err
    (out / "dagger_data" / "iteration_000.pt").write_bytes(b"not a torch file")
    with pytest.raises(SystemExit):
        main(["--preset", "smoke", "--out", str(out), "--resume", *flags])
    assert "iteration_000.pt is not a distiller's labelled data" in capsys.readouterr().err
    (out / "dagger_state.pt").write_bytes(b"not a torch file")
    with pytest.raises(SystemExit):
        main(["--preset", "smoke", "--out", str(out), "--resume", *flags])
    assert "dagger_state.pt is not a distiller's state" in capsys.readouterr().err


@pytest.mark.slow
def test_a_replayed_run_fits_a_bounded_draw_and_writes_what_a_full_one_does(tmp_path, capsys):
    out = tmp_path / "replayed"
    main(["--preset", "smoke", "--out", str(out), "dagger.iterations=3", "dagger.replay=0.5",
          "dagger.steps=8", "dagger.approach=0", "dagger.yardstick=2"])
    rows = list(csv.DictReader((out / "dagger.csv").read_text().splitlines()))
    assert [int(r["samples"]) for r in rows] == [6 * 8 * 8 * k for k in (1, 2, 3)]
    assert all(np.isfinite(float(r["loss"])) for r in rows)
    agent = load_agent(str(out / "checkpoint_final.pt"))
    agent.make_env(2, 0.9, seed=0).rollout(3, agent.policy)


@pytest.mark.slow
def test_a_fine_tune_starts_from_its_checkpoint_and_labels_its_own_states_at_once(
        tmp_path, monkeypatch, capsys):
    """``student.init``: the run starts from the checkpoint's network and frozen normaliser
    (at a learning rate of 1e-12 it ends where it began) and the student drives every
    rollout, iteration 0's included; its resume needs only its own state; a checkpoint of
    another student is refused by the field that differs."""
    flags = ["student.env.num_envs=4", "dagger.steps=6", "dagger.epochs=1",
             "dagger.dagger_epochs=1", "dagger.yardstick=2", "dagger.approach=8",
             "dagger.iterations=1"]
    first, tuned = tmp_path / "first", tmp_path / "tuned"
    main(["--preset", "smoke", "--out", str(first), *flags])
    drivers = []
    original = labels.rollout

    def recorded(*args):
        drivers.append(args[5])  # teacher_drives
        return original(*args)

    monkeypatch.setattr(labels, "rollout", recorded)
    init = str(first / "checkpoint_final.pt")
    main(["--preset", "smoke", "--out", str(tuned), *flags, f"student.init={init}",
          "dagger.lr=1e-12"])
    assert drivers == [False] * 6
    a, b = (torch.load(d / "checkpoint_final.pt", weights_only=True) for d in (first, tuned))
    assert b["trained_by"].startswith(a["trained_by"].split(": ")[0])
    assert f"fine-tuned from {init}" in b["trained_by"]
    for key in a["actor"]:
        torch.testing.assert_close(b["actor"][key], a["actor"][key], rtol=0, atol=1e-8)
    leaves, spec = tree_flatten(a["obs_norm"])
    theirs, their_spec = tree_flatten(b["obs_norm"])
    assert spec == their_spec
    assert all(torch.equal(x, y) if isinstance(x, torch.Tensor) else x == y
               for x, y in zip(leaves, theirs, strict=True))
    # a resumed fine-tune goes on from its own state: the checkpoint it began from may be gone
    moved = tmp_path / "moved.pt"
    (first / "checkpoint_final.pt").rename(moved)
    main(["--preset", "smoke", "--out", str(tuned), *flags[:-1], "dagger.iterations=2",
          f"student.init={init}", "dagger.lr=1e-12", "--resume"])
    assert "resumed after iteration 1 of 2" in capsys.readouterr().out
    moved.rename(first / "checkpoint_final.pt")
    with pytest.raises(SystemExit):
        main(["--preset", "smoke", "--out", str(tmp_path / "other"), *flags,
              f"student.init={init}", "student.model.hidden=[32]"])
    assert (f"student.init: {init} has student.model.hidden=[64, 64], this run "
            f"student.model.hidden=[32]") in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--preset", "smoke", "--out", str(tmp_path / "none"), *flags,
              f"student.init={tmp_path / 'missing.pt'}"])
    assert "student.init: checkpoint" in capsys.readouterr().err
