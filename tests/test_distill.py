"""Distillation (trainers.distill): the teacher's labels are the expert's control (the
planner, then the docking law in its funnel, with no memory the student cannot see); the
final-approach states lie in the law's settled region and carry its control; the labels in
the student's units are what its action map turns into the teacher's control; a DAgger run
writes a checkpoint the evaluator reads as a policy alone; bad settings are refused by
name."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch.utils._pytree import tree_flatten
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import step_mdp

import trainers.distill as distill_module
from tests.test_agent import rows_predict_as_alone
from torchpark import AidsConfig, LotConfig, ParkingConfig, ParkingEnv, SlotGaps
from torchpark.aids.docking import docking_action, error_from_goal
from torchpark.experts import PlannerConfig
from torchpark.experts.planner import plan_control
from torchpark.sim.step import move
from torchpark.transforms.actions import PowerActionMap, gear_inverse, power_map_inverse
from torchpark.transforms.features import GoalFrameFeatures
from trainers.agent import load_agent
from trainers.checkpoint import load_trained
from trainers.config import env_configs, load_config
from trainers.distill import (
    BEST_BY,
    DistillConfig,
    Teacher,
    approach_poses,
    approach_states,
    fit,
    imitation_error,
    main,
    steps_in_stall,
    steps_to_collision,
    student_config,
    teacher_planner,
)
from trainers.evaluate import checkpoint_agent, run_level
from trainers.heads import BinnedGearHead
from trainers.utils import (
    build_models,
    make_base_env,
    make_ppo_models,
    policy_input,
)

COARSE_PLAN = PlannerConfig(cell=1.0, headings=32, step=1.5)  # builds in seconds
HYBRID = ["agent.aids.brake.steer_clear=5", "agent.aids.docking={}",
          "agent.observe_brake=true", "agent.goal_features=true",
          "agent.action_exponents=[1.0,1.0]", "env.task.max_steps=50"]


def write_checkpoint(path, overrides: list[str]) -> str:
    """A checkpoint of the smoke preset with ``overrides``: an untrained policy that drives
    fast and turns (the aids make the rest) and a normaliser fitted to a few of its
    steps."""
    cfg = load_config("smoke", overrides)
    torch.manual_seed(0)
    base = make_base_env(cfg, training=False, num_envs=8, seed=0)
    inputs = policy_input(cfg, base)
    env = TransformedEnv(base, Compose(*inputs))
    actor, _ = make_ppo_models(env.observation_spec["observation_norm"].shape[-1],
                               env.action_spec, cfg.model)
    with torch.no_grad():  # drive fast, turning: into parked cars, for the brake to act
        last = [m for m in actor.modules() if isinstance(m, torch.nn.Linear)][-1]
        last.bias[:2] = torch.tensor([1.5, 0.4])
    env.rollout(20, actor)
    torch.save({"config": dataclasses.asdict(cfg), "frames": 0,
                "actor": actor.state_dict(), "obs_norm": inputs[-1].state_dict()}, path)
    return str(path)


@pytest.fixture(scope="module")
def teacher_path(tmp_path_factory) -> str:
    """The hybrid: brake, steering clear, docking law."""
    return write_checkpoint(tmp_path_factory.mktemp("teacher") / "hybrid.pt", HYBRID)


@pytest.mark.slow
def test_forget_clears_the_aids_state_of_ended_rows(teacher_path):
    paper = ParkingEnv(4, seed=0, config=ParkingConfig(max_steps=200))
    teacher = Teacher(teacher_path, TransformedEnv(paper), planner=COARSE_PLAN)
    teacher.state = teacher.state._replace(braked=torch.ones(4, dtype=torch.bool),
                                           docking_engaged=torch.ones(4, dtype=torch.bool))
    teacher.forget(torch.tensor([True, False, True, False]))
    assert teacher.state.braked.tolist() == [False, True, False, True]
    assert teacher.state.docking_engaged.tolist() == [False, True, False, True]


@pytest.mark.slow
def test_the_planner_teacher_drives_the_planner_then_the_law_in_its_target(teacher_path):
    paper = ParkingEnv(16, seed=3, config=ParkingConfig(occupancy=0.9))
    teacher = Teacher(teacher_path, TransformedEnv(paper), planner=COARSE_PLAN)
    law = teacher.aids.docking
    assert (law.reach, law.lateral, law.heading) == (COARSE_PLAN.reach, COARSE_PLAN.lateral,
                                                        COARSE_PLAN.heading)
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


def test_the_inverse_power_map_gives_what_the_map_turns_into_the_control():
    high, exponents = torch.tensor([5.0, 0.785]), torch.tensor([3.0, 1.0])
    control = torch.tensor([[1e-3, 0.0], [-2.0, 0.3], [4.9, -0.78], [-1e-4, 1e-4]])
    u = power_map_inverse(control, high, exponents)
    assert (u.abs() < 1).all()
    assert u[0, 0].item() == pytest.approx((1e-3 / 5.0) ** (1 / 3))  # 1 mm/s: 0.058
    td = PowerActionMap(high, exponents).inv(TensorDict({"action": u}, [4]))
    torch.testing.assert_close(td["action"], control, rtol=1e-5, atol=1e-8)


@pytest.mark.slow
def test_approach_poses_lie_in_the_laws_settled_approach_denser_near_the_goal(teacher_path):
    cfg, _ = load_trained(teacher_path)
    law = env_configs(cfg, training=False)[1].docking
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
def test_approach_states_carry_the_laws_forward_control(teacher_path):
    cfg, _ = load_trained(teacher_path)
    law = env_configs(cfg, training=False)[1].docking
    paper = ParkingEnv(64, seed=5, config=ParkingConfig(max_steps=200))
    paper.occupancy = 0.9
    features = GoalFrameFeatures()
    env = TransformedEnv(paper, features)
    teacher = Teacher(teacher_path, env, planner=COARSE_PLAN)
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


@pytest.mark.parametrize("field, value", [("iterations", 0), ("iterations", True),
                                          ("envs", 1.5), ("near_goal", 2.0),
                                          ("noise", float("nan")), ("lr", -1.0),
                                          ("approach", -1), ("approach", 0.5),
                                          ("approach_weight", 0.0),
                                          ("collision_weight", 0.0),
                                          ("collision_weight", float("inf")),
                                          ("collision_horizon", 0),
                                          ("stall_from", 0), ("stall_from", 1.5),
                                          ("speed_exponent", 0.5),
                                          ("steer_exponent", float("inf")),
                                          ("dagger_epochs", 0), ("lr_decay", 1),
                                          ("settle", -0.01), ("settle", float("nan")),
                                          ("retry", -1.0), ("retry", float("inf")),
                                          ("reverse_margin", -0.5),
                                          ("reverse_margin", float("nan")),
                                          ("gear_hold", -0.5), ("gear_hold", float("nan")),
                                          ("target_lateral", 0.0),
                                          ("target_lateral", float("inf")),
                                          ("target_heading", -0.1), ("target_heading", 4.0),
                                          ("funnel_lateral", 0.0),
                                          ("funnel_lateral", 0.1),  # inside the target's
                                          ("funnel_heading", 4.0),
                                          ("funnel_heading", 0.1),
                                          ("planner_headings", 7),
                                          ("planner_headings", 2000),
                                          ("handover", -1), ("handover", 1001),
                                          ("handover", 2.5),
                                          ("steer_bins", 4), ("steer_bins", 1),
                                          ("steer_bins", 257),
                                          ("width", 0), ("width", True), ("depth", 9),
                                          ("depth", 2.0),
                                          ("slot_features", True)])  # without position
def test_bad_settings_are_refused_by_name(field, value):
    with pytest.raises((ValueError, TypeError), match=rf"DistillConfig\.{field}"):
        DistillConfig(**{field: value})


def test_the_command_line_names_the_flag_of_a_funnel_inside_the_target(capsys):
    with pytest.raises(SystemExit) as refused:
        main(["teacher.pt", "--out", "student", "--funnel-lateral", "0.1"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert refused.value.code == 2 and "PlannerConfig" not in err
    assert "DistillConfig.funnel_lateral (--funnel-lateral) must be" in err, err
    assert "[DistillConfig.target_lateral = 0.5, inf]" in err


@pytest.fixture
def coarse_planner(monkeypatch):
    """The command line's runs with the coarse planner (the default's tables take minutes)."""
    monkeypatch.setattr(distill_module, "PlannerConfig", lambda: COARSE_PLAN)


@pytest.mark.slow
def test_a_run_writes_a_policy_alone_the_evaluator_reads(teacher_path, tmp_path, capsys,
                                                         coarse_planner):
    out = tmp_path / "student"
    args = [teacher_path, "--out", str(out), "--iterations", "2", "--envs", "8",
            "--steps", "20", "--epochs", "1", "--dagger-epochs", "1", "--yardstick", "4",
            "--approach", "16"]
    main(args)
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert cfg.agent.aids.brake is None and cfg.agent.aids.docking is None
    assert cfg.agent.aids.action_repeat == 1 and cfg.agent.action_exponents == [3.0, 1.0]
    assert cfg.agent.gear_head
    made_of = checkpoint_agent(str(out / "checkpoint_final.pt")).made_of
    assert made_of["agent"] == "policy alone"
    assert made_of["policy"].startswith("distilled (gear head) from the approach planner")
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
def test_a_student_with_the_clearance_features_and_position_reads_them_everywhere(
        teacher_path, tmp_path, coarse_planner):
    """The rays' clearance and the car's position join the student's input in its rollouts,
    its final-approach states and the evaluator's env alike."""
    out = tmp_path / "clearance"
    main([teacher_path, "--out", str(out), "--iterations", "1", "--envs", "4", "--steps",
          "5", "--epochs", "1", "--yardstick", "2", "--approach", "8",
          "--clearance-features", "--position"])
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert cfg.agent.clearance_features and cfg.agent.goal_features
    assert cfg.agent.aids.observe_position
    assert checkpoint["trained_by"].startswith(
        "distilled (gear head, clearance features, position) from")
    loc = checkpoint["obs_norm"]["_extra_state"]["loc.-|-.observation_policy"]
    assert loc.shape[-1] == 23 + 7 + 16 + 2
    agent = load_agent(str(out / "checkpoint_final.pt"))
    agent.make_env(2, 0.9, seed=0).rollout(3, agent.policy)


@pytest.mark.slow
def test_a_student_with_the_gear_features_reads_them_everywhere(teacher_path, tmp_path,
                                                                coarse_planner):
    """The gear and its travel join the student's input (after the clearance, before the
    position) in its rollouts, its final-approach states and the evaluator's env alike."""
    out = tmp_path / "gear"
    main([teacher_path, "--out", str(out), "--iterations", "2", "--envs", "4", "--steps",
          "5", "--epochs", "1", "--dagger-epochs", "1", "--yardstick", "2", "--approach",
          "8", "--clearance-features", "--gear-features", "--position", "--gear-hold",
          "0.5"])
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert cfg.agent.gear_features
    assert checkpoint["trained_by"].startswith(
        "distilled (gear head, clearance features, gear features, position) from")
    data = torch.load(out / "dagger_data" / "iteration_001.pt")
    assert data[0].shape[-1] == 23 + 7 + 16 + 2 + 2
    gear, travel = data[0][:, -4], data[0][:, -3]
    assert set(gear.unique().tolist()) <= {-1.0, 0.0, 1.0}
    assert bool(((travel >= 0) & (travel <= 1)).all()) and bool((travel < 1).any())
    agent = load_agent(str(out / "checkpoint_final.pt"))
    agent.make_env(2, 0.9, seed=0).rollout(3, agent.policy)


@pytest.mark.slow
def test_a_student_with_a_scan_memory_reads_it_everywhere_and_predicts_with_it(
        teacher_path, tmp_path, coarse_planner):
    """The scan memory joins the student's input (after the gear features, before the
    position) in its rollouts and its final-approach states; its Gymnasium ``predict``
    carries the memory as a recurrent state and drives the evaluator's episode to the last
    bit, and a batch's row flagged as a new episode's start forgets it."""
    out = tmp_path / "memory"
    main([teacher_path, "--out", str(out), "--iterations", "2", "--envs", "4", "--steps",
          "5", "--epochs", "1", "--dagger-epochs", "1", "--yardstick", "2", "--approach",
          "8", "--clearance-features", "--gear-features", "--position", "--scan-memory", "2"])
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert cfg.agent.scan_memory == 2
    assert checkpoint["trained_by"].startswith("distilled (gear head, clearance features, "
                                               "gear features, a memory of 2 scans, position)")
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
def test_a_student_with_the_slot_features_reads_them_everywhere(teacher_path, tmp_path,
                                                                coarse_planner):
    """The slots' gaps join the student's input (before the position) in its rollouts and
    its final-approach states, each row's the features of its own observation and position;
    its Gymnasium ``predict`` reads the position from ``info`` and drives the evaluator's
    episode to the last bit."""
    out = tmp_path / "slots"
    main([teacher_path, "--out", str(out), "--iterations", "2", "--envs", "4", "--steps",
          "5", "--epochs", "1", "--dagger-epochs", "1", "--yardstick", "2", "--approach",
          "8", "--position", "--slot-features"])
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert cfg.agent.slot_features
    assert checkpoint["trained_by"].startswith("distilled (gear head, slot features, "
                                               "position) from")
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
def test_a_student_with_binned_steering_is_fitted_and_driven_by_its_bins(teacher_path,
                                                                          tmp_path,
                                                                          coarse_planner):
    out = tmp_path / "bins"
    main([teacher_path, "--out", str(out), "--iterations", "2", "--envs", "4", "--steps",
          "5", "--epochs", "1", "--dagger-epochs", "1", "--yardstick", "2", "--approach",
          "8", "--steer-bins", "5", "--collision-weight", "4", "--collision-horizon", "3"])
    cfg, checkpoint = load_trained(str(out / "checkpoint_final.pt"))
    assert cfg.model.steer_bins == 5
    assert checkpoint["trained_by"].startswith("distilled (gear head, binned steering) from")
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
def test_a_rollout_counts_the_steps_to_the_drivers_collisions(teacher_path):
    # A driver that floors it forwards, turning a little, at 90 %: into the parked cars.
    scfg = student_config(teacher_path, DistillConfig())
    base = make_base_env(scfg, training=True, num_envs=8, seed=0)
    base.occupancy = 0.9
    inputs = policy_input(scfg, base)
    env = TransformedEnv(base, Compose(*inputs))
    teacher = Teacher(teacher_path, env, planner=COARSE_PLAN)
    floor_it = torch.tensor([1.0, 1.0, 0.3, 1.0, 0.0])  # gear, (speed, steer) per gear

    def driver(td):
        return td.set("action", floor_it.expand(td.shape[0], 5))

    steps = 40
    x, y, ahead, stalled = distill_module.rollout(
        env, driver, teacher, torch.tensor([3.0, 1.0]), steps, False, 0.0,
        torch.Generator().manual_seed(0))
    assert x.shape[0] == y.shape[0] == ahead.shape[0] == stalled.shape[0] == steps * 8
    assert not stalled.any()  # 40 steps: no 100-step window fits
    ahead = ahead.reshape(steps, 8)
    assert (ahead == 1).sum() >= 4  # collisions
    # Within a row the count runs down by one a step to the colliding step's 1.
    before = ahead[:-1].isfinite() & (ahead[:-1] > 1)
    assert torch.equal(ahead[1:][before], ahead[:-1][before] - 1)


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
def test_the_students_layers_are_the_teachers_unless_width_or_depth_is_given(teacher_path):
    teacher = load_trained(teacher_path)[0].model.hidden
    sizes = {(width, depth): student_config(teacher_path, DistillConfig(width=width, depth=depth)
                                            ).model.hidden
             for width in (None, 24) for depth in (None, 3)}
    assert sizes == {(None, None): teacher, (24, None): [24] * len(teacher),
                     (None, 3): [teacher[0]] * 3, (24, 3): [24] * 3}
    actor, _ = build_models(student_config(teacher_path, DistillConfig(width=24, depth=3)))
    linears = [m for m in actor.modules() if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in linears[:-1]] == [24] * 3


@pytest.mark.slow
@pytest.mark.parametrize("lr_decay", [False, True])
def test_each_fit_starts_at_lr_and_decays_to_zero_if_asked(teacher_path, lr_decay):
    cfg = DistillConfig(lr=1e-3, lr_decay=lr_decay, batch_size=16)
    scfg = student_config(teacher_path, cfg)
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
        fit(actor, norm.to_observation_norm(), x, y, torch.ones(64), 3, cfg, optim, generator)
        assert any(not torch.equal(a, b) for a, b in zip(before, actor.parameters(), strict=True))
        lr = optim.param_groups[0]["lr"]
        assert lr == (pytest.approx(0.0, abs=1e-12) if lr_decay else cfg.lr)


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
def test_with_settle_the_planner_teacher_creeps_back_from_just_past_the_goal(teacher_path):
    paper = past_the_goal(torch.zeros(16))
    speeds = {}
    for settle in (0.0, 0.05):
        teacher = Teacher(teacher_path, TransformedEnv(paper), planner=COARSE_PLAN,
                          settle=settle)
        speeds[settle] = teacher.label()[:, 0]
    law = teacher.aids.docking
    creep = max(law.speed_gain * 2e-3, law.min_speed)
    torch.testing.assert_close(speeds[0.05], torch.full((16,), -creep), rtol=1e-3, atol=1e-6)
    # without: the planner's pass at full speed, wherever the coarse planner finds a way out
    moving = speeds[0.0] != 0
    assert moving.sum() >= 8 and (speeds[0.0][moving].abs() > 100 * creep).all()


@pytest.mark.slow
def test_with_retry_the_planner_teacher_backs_out_where_the_test_cannot_pass(teacher_path):
    # half the rows 3 mm to the side (a near miss), half 0.1 mm (fine)
    paper = past_the_goal(torch.where(torch.arange(16) % 2 == 0, 3e-3, 1e-4))
    teacher = Teacher(teacher_path, TransformedEnv(paper), planner=COARSE_PLAN, settle=0.05,
                      retry=1.0)
    speed = teacher.label()[:, 0]
    law = teacher.aids.docking
    assert law.retry == 1.0 and law.settle == 0.05
    creep = max(law.speed_gain * 2e-3, law.min_speed)
    torch.testing.assert_close(speed[1::2], torch.full((8,), -creep), rtol=1e-3, atol=1e-6)
    # the near misses: the law's pass back, at full speed (not the planner's way out of the
    # slot, forwards or backwards wherever its tables say)
    assert (speed[0::2] == -law.max_speed).all()


@pytest.mark.slow
def test_with_a_reverse_margin_the_law_turns_forwards_short_of_contact(teacher_path):
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
    speed = {margin: Teacher(teacher_path, TransformedEnv(paper), planner=COARSE_PLAN,
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
def test_a_reverse_margin_past_the_lots_thinnest_obstacle_is_refused(teacher_path, wall,
                                                                    margin):
    # the look-ahead tests the one pose that far back: beyond the thinnest obstacle it
    # could step over a wall
    paper = ParkingEnv(2, config=ParkingConfig(lot=LotConfig(wall_thickness=wall)))
    with pytest.raises(ValueError, match=rf"^reverse_margin must be in \[0, {wall:g}\] m"):
        Teacher(teacher_path, TransformedEnv(paper), planner=COARSE_PLAN,
                reverse_margin=margin)


WIDE_PLAN = dataclasses.replace(COARSE_PLAN, law_lateral=2.0, law_heading=1.0)


@pytest.mark.slow
def test_with_a_handover_look_ahead_the_law_takes_over_only_where_it_would_touch_nothing(
        teacher_path):
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
        return Teacher(teacher_path, TransformedEnv(paper), planner=plan,
                       handover=handover).label()

    wide = Teacher(teacher_path, TransformedEnv(paper), planner=WIDE_PLAN)
    planner_label, law_label = label(COARSE_PLAN), wide.label()
    looked = label(WIDE_PLAN, horizon)
    # the oracle: the env itself, the law (the wide funnel's, no brake) driving every lot
    lots = ParkingEnv(n, seed=5, config=ParkingConfig(occupancy=0.9),
                      aids=AidsConfig(docking=wide.aids.docking))
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
def test_a_handover_out_of_range_is_refused(teacher_path, handover):
    paper = ParkingEnv(2)
    with pytest.raises(ValueError, match=r"^handover must be an int in \[0, 1000\]"):
        Teacher(teacher_path, TransformedEnv(paper), planner=WIDE_PLAN, handover=handover)


@pytest.mark.slow
def test_a_resumed_run_gives_the_checkpoints_of_a_run_never_stopped(teacher_path, tmp_path,
                                                                    capsys, coarse_planner):
    flags = ["--envs", "8", "--steps", "12", "--epochs", "2", "--dagger-epochs", "1",
             "--yardstick", "4", "--approach", "16", "--position", "--steer-bins", "5"]
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    main([teacher_path, "--out", str(whole), "--iterations", "3", *flags])
    main([teacher_path, "--out", str(parts), "--iterations", "1", *flags])
    main([teacher_path, "--out", str(parts), "--iterations", "3", "--resume", *flags])
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
def test_resuming_refuses_what_would_not_continue_the_run(teacher_path, tmp_path, capsys,
                                                         coarse_planner):
    """Each refusal names what is wrong and leaves the run's state as it was (one run for
    the three: each refused command changes nothing, the test checks)."""
    flags = ["--envs", "4", "--steps", "4", "--epochs", "1", "--dagger-epochs", "1",
             "--yardstick", "2", "--approach", "0"]
    out = tmp_path / "run"
    main([teacher_path, "--out", str(out), "--iterations", "2", *flags])
    capsys.readouterr()
    before = (out / "dagger_state.pt").read_bytes()
    for change, error in (
            (["--iterations", "1", "--resume"], "--iterations must be >= 2"),
            (["--iterations", "3", "--resume", "--lr", "0.01"],
             "has lr=0.001, this command lr=0.01"),
            (["--iterations", "3", "--resume", "--overwrite"], "pass one of them")):
        with pytest.raises(SystemExit):
            main([teacher_path, "--out", str(out), *flags, *change])
        assert error in capsys.readouterr().err
        assert (out / "dagger_state.pt").read_bytes() == before


@pytest.mark.slow
def test_a_run_saved_before_a_setting_existed_resumes_at_its_default(teacher_path, tmp_path,
                                                                    capsys, coarse_planner):
    flags = ["--envs", "4", "--steps", "4", "--epochs", "1", "--dagger-epochs", "1",
             "--yardstick", "2", "--approach", "0"]
    out = tmp_path / "run"
    main([teacher_path, "--out", str(out), "--iterations", "1", *flags])
    state = torch.load(out / "dagger_state.pt", weights_only=True)
    del state["distill"]["gear_hold"]  # as a run saved before gear_hold was added
    torch.save(state, out / "dagger_state.pt")
    main([teacher_path, "--out", str(out), "--iterations", "2", "--resume", *flags])
    assert "resumed after iteration 1 of 2" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main([teacher_path, "--out", str(out), "--iterations", "3", "--resume",
              "--gear-hold", "0.5", *flags])
    assert "has gear_hold=0.0, this command gear_hold=0.5" in capsys.readouterr().err
    # a setting this distiller has dropped since the run was saved is refused by name
    state = torch.load(out / "dagger_state.pt", weights_only=True)
    state["distill"]["hazard_weight"] = 0.1
    torch.save(state, out / "dagger_state.pt")
    before = (out / "dagger_state.pt").read_bytes()
    with pytest.raises(SystemExit):
        main([teacher_path, "--out", str(out), "--iterations", "3", "--resume", *flags])
    assert ("has hazard_weight=0.1, a setting this distiller no longer has"
            in capsys.readouterr().err)
    assert (out / "dagger_state.pt").read_bytes() == before


def test_the_teachers_planner_takes_the_runs_hold_and_target():
    assert teacher_planner(DistillConfig()) == PlannerConfig()
    tight = DistillConfig(gear_hold=0.75, target_lateral=0.25, target_heading=0.12)
    assert teacher_planner(tight) == PlannerConfig(gear_hold=0.75, lateral=0.25, heading=0.12)
    assert teacher_planner(tight, COARSE_PLAN) == dataclasses.replace(
        COARSE_PLAN, gear_hold=0.75, lateral=0.25, heading=0.12)
    assert teacher_planner(DistillConfig(target_heading=0.1), COARSE_PLAN).lateral \
        == COARSE_PLAN.lateral
    wide = DistillConfig(planner_headings=96, funnel_lateral=0.6, funnel_heading=0.55)
    assert teacher_planner(wide) == PlannerConfig(headings=96, law_lateral=0.6,
                                                  law_heading=0.55)


@pytest.mark.slow
def test_the_teachers_gear_hold_follows_the_car(teacher_path):
    """Labelling states a student drove: every car has just reversed, so the teacher with a
    hold labels what the planner gives when each keeps its gear, where the greedy one
    would turn some of them forwards."""
    paper = ParkingEnv(256, seed=2)
    env = TransformedEnv(paper)
    free = Teacher(teacher_path, env, planner=COARSE_PLAN)
    held = Teacher(teacher_path, env, planner=dataclasses.replace(COARSE_PLAN, gear_hold=5.0))
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


@pytest.mark.slow
def test_resuming_refuses_another_teacher_or_no_run(teacher_path, tmp_path, capsys,
                                                    coarse_planner):
    flags = ["--envs", "4", "--steps", "4", "--epochs", "1", "--dagger-epochs", "1",
             "--yardstick", "2", "--approach", "0", "--iterations", "2"]
    with pytest.raises(SystemExit):
        main([teacher_path, "--out", str(tmp_path / "empty"), "--resume", *flags])
    assert "dagger_state.pt does not exist" in capsys.readouterr().err
    out = tmp_path / "run"
    main([teacher_path, "--out", str(out), *flags[:-1], "1"])
    other = tmp_path / "other.pt"
    torch.save({**torch.load(teacher_path, weights_only=True), "frames": 1}, other)
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main([str(other), "--out", str(out), "--resume", *flags])
    assert "distilled from another teacher" in capsys.readouterr().err
    (out / "dagger_data" / "iteration_000.pt").write_bytes(b"not a torch file")
    with pytest.raises(SystemExit):
        main([teacher_path, "--out", str(out), "--resume", *flags])
    assert "iteration_000.pt is not a distiller's labelled data" in capsys.readouterr().err
    (out / "dagger_state.pt").write_bytes(b"not a torch file")
    with pytest.raises(SystemExit):
        main([teacher_path, "--out", str(out), "--resume", *flags])
    assert "dagger_state.pt is not a distiller's state" in capsys.readouterr().err
