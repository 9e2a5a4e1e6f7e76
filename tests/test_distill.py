"""Distillation (trainers.distill): the teacher's labels are the hybrid agent's control, so
the paper's env driven by them follows the hybrid env's path; a DAgger run writes a
checkpoint the evaluator reads as a policy alone; bad settings are refused by name."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchpark import ParkingConfig, ParkingEnv
from torchpark.aids.docking import error_from_goal, in_funnel
from trainers.config import env_configs, load_config
from trainers.distill import DistillConfig, Teacher, asinh_loss, main
from trainers.evaluate import composition, load
from trainers.utils import make_base_env, make_eval_env, make_policy, make_ppo_models, policy_input

HYBRID = ["agent.emergency_brake=true", "agent.steer_clear=5", "agent.docking=true",
          "agent.observe_brake=true", "agent.goal_features=true",
          "agent.action_exponents=[1.0,1.0]", "env.max_steps=200"]


@pytest.fixture(scope="module")
def teacher_path(tmp_path_factory) -> str:
    """A hybrid checkpoint with an untrained policy that drives fast and turns (the aids
    make the rest) and a normaliser fitted to a few of its steps."""
    cfg = load_config("smoke", HYBRID)
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
    path = tmp_path_factory.mktemp("teacher") / "hybrid.pt"
    torch.save({"config": dataclasses.asdict(cfg), "frames": 0,
                "actor": actor.state_dict(), "obs_norm": inputs[-1].state_dict()}, path)
    return str(path)


def test_the_paper_env_driven_by_the_labels_follows_the_hybrid(teacher_path):
    cfg, checkpoint = load(teacher_path)
    n, occupancy = 32, 0.9
    hybrid = make_eval_env(cfg, checkpoint["obs_norm"], occupancy, n, seed=7)
    actor = make_policy(cfg, checkpoint["actor"])
    paper = ParkingEnv(n, seed=7, config=ParkingConfig(max_steps=cfg.env.max_steps))
    paper.occupancy = occupancy
    teacher = Teacher(teacher_path, TransformedEnv(paper))
    hybrid_td, paper_td = hybrid.reset(), paper.reset()
    assert torch.equal(hybrid.base_env.state.pose, paper.state.pose)
    moved = steered = docked = 0
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(150):
            label = teacher.label(paper_td["observation"])
            hybrid_td = hybrid.step(actor(hybrid_td))
            paper_td = paper.step(paper_td.set("action", label))
            torch.testing.assert_close(paper.state.pose, hybrid.base_env.state.pose,
                                       atol=1e-5, rtol=0)
            assert not paper_td["next", "collision"].any()
            assert torch.equal(teacher.state.braked, hybrid_td["next", "braked"][:, 0])
            moved += int((label[:, 0] != 0).sum())
            steered += int(hybrid_td["next", "interventions"].sum() > 0)
            docked += int(hybrid_td["next", "docking_engaged"].sum())
            assert not hybrid_td["next", "done"].any()
            hybrid_td, paper_td = hybrid_td["next"], paper_td["next"]
    assert moved and steered and docked  # the brake and the law both acted


def test_forget_clears_the_aids_state_of_ended_rows(teacher_path):
    paper = ParkingEnv(4, seed=0, config=ParkingConfig(max_steps=200))
    teacher = Teacher(teacher_path, TransformedEnv(paper))
    teacher.state = teacher.state._replace(braked=torch.ones(4, dtype=torch.bool),
                                           docking_engaged=torch.ones(4, dtype=torch.bool))
    teacher.forget(torch.tensor([True, False, True, False]))
    assert teacher.state.braked.tolist() == [False, True, False, True]
    assert teacher.state.docking_engaged.tolist() == [False, True, False, True]


def test_a_teacher_without_aids_is_refused(tmp_path):
    cfg = load_config("smoke")
    path = tmp_path / "plain.pt"
    torch.save({"config": dataclasses.asdict(cfg), "frames": 0, "actor": {},
                "obs_norm": {}}, path)
    with pytest.raises(ValueError, match="neither the brake nor the docking law"):
        Teacher(str(path), TransformedEnv(ParkingEnv(2, seed=0)))


def test_asinh_loss_is_linear_below_the_precision_and_relative_above():
    precision = torch.tensor([1e-4])
    small = asinh_loss(torch.tensor([[2e-5]]), torch.tensor([[1e-5]]), precision)
    assert small.item() == pytest.approx(0.1 ** 2, rel=0.03)
    # a 10 % error weighs about the same at 1 m/s and at 1 cm/s
    big = asinh_loss(torch.tensor([[1.1]]), torch.tensor([[1.0]]), precision)
    mid = asinh_loss(torch.tensor([[1.1e-2]]), torch.tensor([[1e-2]]), precision)
    assert big.item() == pytest.approx(mid.item(), rel=1e-2)


@pytest.mark.parametrize("field, value", [("iterations", 0), ("iterations", True),
                                          ("envs", 1.5), ("near_goal", 2.0),
                                          ("noise", float("nan")), ("lr", -1.0),
                                          ("speed_precision", 0.0)])
def test_bad_settings_are_refused_by_name(field, value):
    with pytest.raises((ValueError, TypeError), match=rf"DistillConfig\.{field}"):
        DistillConfig(**{field: value})


def test_a_run_writes_a_policy_alone_the_evaluator_reads(teacher_path, tmp_path, capsys):
    out = tmp_path / "student"
    args = [teacher_path, "--out", str(out), "--iterations", "2", "--envs", "8",
            "--steps", "20", "--epochs", "1", "--yardstick", "4"]
    main(args)
    cfg, checkpoint = load(str(out / "checkpoint_final.pt"))
    assert not (cfg.agent.emergency_brake or cfg.agent.docking)
    assert cfg.agent.action_repeat == 1
    made_of = composition(cfg, checkpoint)
    assert made_of["agent"] == "policy alone" and made_of["policy"].startswith("DAgger")
    assert checkpoint["frames"] == 2 * 6 * 20 * 8
    rows = (out / "dagger.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[0].startswith("iteration,frames")
    with pytest.raises(SystemExit):
        main(args)  # the checkpoint exists: refused without --overwrite
    assert "--overwrite" in capsys.readouterr().err


def test_release_lets_the_law_go_of_a_student_far_from_its_slot(teacher_path):
    cfg, _ = load(teacher_path)
    paper = ParkingEnv(64, seed=3, config=ParkingConfig(max_steps=200))
    td = paper.reset()
    law = env_configs(cfg, training=False)[1].docking
    error = error_from_goal(paper.state.pose, paper.state.goal)
    far = ((error.remaining < -1.0) | (error.remaining > law.run_in + 1.0)
           | (error.lateral.abs() > law.lateral + 1.0))
    assert 0 < int(far.sum()) < 64
    for release, kept in ((None, torch.ones(64, dtype=torch.bool)), (1.0, ~far)):
        teacher = Teacher(teacher_path, TransformedEnv(paper), release)
        engaged = torch.ones(64, dtype=torch.bool)
        teacher.state = teacher.state._replace(docking_engaged=engaged)
        teacher.label(td["observation"])
        assert torch.equal(teacher.state.docking_engaged, kept | in_funnel(error, law))
