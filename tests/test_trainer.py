"""The PPO trainer: the smoke preset end to end, TensorBoard tags, checkpoints, resume, errors."""

from __future__ import annotations

import csv
import dataclasses
import math
import shutil
import subprocess
import sys
import textwrap
import time
import typing
from functools import partial
from pathlib import Path

import imageio.v3 as iio
import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensordict import TensorDict
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.objectives import ClipPPOLoss

from torchpark import (
    DockingConfig,
    ParkingConfig,
)
from torchpark.files import locked
from torchpark.transforms.features import GOAL_FEATURES
from trainers.config import ModelConfig, TrainConfig, env_configs, load_config
from trainers.evaluate import COLUMNS, evaluate
from trainers.evaluate import main as evaluate_main
from trainers.ppo import main, ppo_step, recompute_log_prob_, train
from trainers.utils import NORMALISED, make_env, make_ppo_models, reset_exploration

TAGS = {
    "episode/reward", "episode/length", "episode/success_rate", "episode/collision_rate",
    "episode/timeout_rate", "curriculum/occupancy", "curriculum/phase",
    "curriculum/success_threshold", "loss/objective",
    "loss/critic", "time/fps", "time/collect_fps", "time/train_fps",
}


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    log_dir = tmp_path_factory.mktemp("runs")
    cfg = load_config("smoke", [f"logger.log_dir={log_dir}"])
    return cfg, train(cfg)


@pytest.mark.slow
def test_smoke_preset_trains_and_logs(smoke_run):
    cfg, final = smoke_run
    run_dir = final.parent
    events = EventAccumulator(str(run_dir))
    events.Reload()
    assert TAGS <= set(events.Tags()["scalars"])
    phases = [e.value for e in events.Scalars("curriculum/phase")]
    assert phases == sorted(phases) and phases[-1] > 1  # 4 x 1024 frames, 1024 per level
    ckpt = torch.load(final, weights_only=True)
    assert ckpt["frames"] == cfg.collector.total_frames
    assert ckpt["config"] == dataclasses.asdict(cfg)
    assert {"actor", "critic", "optim", "env"} <= set(ckpt)
    assert (run_dir / "checkpoint_2048.pt").exists()


@pytest.mark.slow
def test_resume_keeps_frames_and_curriculum(smoke_run, tmp_path):
    _, final = smoke_run
    frames = [int(v) for k, v in torch.load(final, weights_only=True)["env"].items()
              if k.endswith("frames")]
    assert frames == [4096]
    main(["--preset", "smoke", "--resume", str(final), f"logger.log_dir={tmp_path}",
          "collector.total_frames=6144"])
    resumed = torch.load(tmp_path / "smoke" / "checkpoint_final.pt", weights_only=True)
    assert resumed["frames"] == 6144
    assert [int(v) for k, v in resumed["env"].items() if k.endswith("frames")] == [6144]


@pytest.mark.slow
def test_a_resumed_run_equals_the_uninterrupted_one_bit_for_bit(smoke_run, tmp_path):
    """The smoke run saved a checkpoint half way (2,048 of 4,096 frames); resumed from it in
    another directory, the second half repeats the uninterrupted run exactly: the same
    networks, optimiser state, normalisation statistics and env snapshot at the end."""
    _, final = smoke_run
    half = final.parent / "checkpoint_2048.pt"
    main(["--preset", "smoke", "--resume", str(half), f"logger.log_dir={tmp_path}"])
    whole = torch.load(final, weights_only=True)
    resumed = torch.load(tmp_path / "smoke" / "checkpoint_final.pt", weights_only=True)
    assert resumed["frames"] == whole["frames"] == 4096
    for key in ("actor", "critic", "optim", "obs_norm", "env", "sim", "carrier", "rng"):
        torch.testing.assert_close(resumed[key], whole[key], rtol=0, atol=0, msg=key)


@pytest.mark.slow
def test_a_run_started_from_a_checkpoint_begins_with_its_actor_and_statistics(smoke_run,
                                                                              tmp_path):
    """--init: the run's actor is the checkpoint's with its std reset to the run's
    model.init_log_std (a one-batch run whose steps are below float32's resolution, lr
    1e-30, ends with exactly that), on the checkpoint's observation statistics, frozen; the
    critic is fresh, the frames count from zero, and the evaluator's policy column names the
    start."""
    _, final = smoke_run
    start = torch.load(final, weights_only=True)
    main(["--preset", "smoke", "--init", str(final), f"logger.log_dir={tmp_path}",
          "optim.lr=1e-30", "model.init_log_std=-2", "collector.total_frames=1024"])
    run = torch.load(tmp_path / "smoke" / "checkpoint_final.pt", weights_only=True)
    assert run["frames"] == 1024 and run["started_from"] == str(final)
    assert any(key.endswith("log_std") for key in start["actor"])
    for key, value in start["actor"].items():
        expected = torch.full_like(value, -2.0) if key.endswith("log_std") else value
        torch.testing.assert_close(run["actor"][key], expected, rtol=0, atol=0, msg=key)
    assert not torch.equal(run["critic"]["module.0.weight"], start["critic"]["module.0.weight"])
    # The statistics are the checkpoint's, frozen (the smoke run's moved in every batch).
    torch.testing.assert_close(run["obs_norm"], start["obs_norm"], rtol=0, atol=0)
    half = torch.load(final.parent / "checkpoint_2048.pt", weights_only=True)["obs_norm"]
    assert any(not torch.equal(v, half["_extra_state"][k])
               for k, v in start["obs_norm"]["_extra_state"].items() if k.startswith("var"))
    row = evaluate(str(tmp_path / "smoke" / "checkpoint_final.pt"), episodes=2, levels=[0.0])[0]
    assert row["policy"].endswith(f"from {final}")


@pytest.mark.parametrize("state_dependent", [True, False])
def test_reset_exploration_sets_the_std_everywhere_and_keeps_the_mean(state_dependent):
    spec = Bounded(-1.0, 1.0, shape=(3,))
    cfg = ModelConfig(hidden=[8], init_log_std=-2.5, state_dependent_std=state_dependent)
    actor, _ = make_ppo_models(4, spec, cfg)
    with torch.no_grad():
        for p in actor.parameters():
            p.add_(torch.randn_like(p))  # a trained actor: its std varies with the state
    td = TensorDict({NORMALISED: torch.randn(64, 4)}, [64])
    before = actor.module[0](td.clone())
    assert before["scale"].std() > 0.01 or not state_dependent
    reset_exploration(actor, cfg)
    after = actor.module[0](td.clone())
    torch.testing.assert_close(after["loc"], before["loc"], rtol=0, atol=0)
    torch.testing.assert_close(after["scale"], torch.full_like(after["scale"], math.exp(-2.5)))


def saturated_draws(mean: float = 12.0):
    """An actor whose pre-tanh mean is ``mean`` (a distilled gear's, say) in both action
    dimensions, std e^-2 = 0.135, and 256 of its draws with advantages and value targets:
    (actor, critic, batch)."""
    spec = Bounded(-1.0, 1.0, shape=(2,))
    cfg = ModelConfig(hidden=[8], init_log_std=-2.0, state_dependent_std=True)
    actor, critic = make_ppo_models(4, spec, cfg)
    with torch.no_grad():
        actor.module[0].module[0][-1].bias[:2] = mean
    td = TensorDict({NORMALISED: torch.randn(256, 4)}, [256])
    with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
        td = actor(td)
    td["advantage"] = torch.randn(256, 1)
    td["value_target"] = torch.randn(256, 1)
    return actor, critic, td


def test_the_recomputed_log_prob_makes_the_first_ratio_one_on_saturated_draws():
    """The log-probability sampled with a saturated action and the one the loss recomputes
    from the float32 action differ by hundreds of nats; after recompute_log_prob_ the
    loss's ratio is exactly one before any step."""
    actor, critic, td = saturated_draws()
    key = "action_log_prob"
    stored = td[key].clone()
    loss = ClipPPOLoss(actor, critic, normalize_advantage=False)
    assert (loss(td.clone())["kl_approx"].abs() > 1).item()
    recompute_log_prob_(actor, td, loss.tensor_keys.sample_log_prob)
    assert (td[key] - stored).abs().max() > 100
    assert loss(td.clone())["kl_approx"].item() == 0.0


@pytest.mark.slow
def test_the_compiled_update_takes_the_eager_updates_steps():
    """optim.compile_update: three PPO updates through torch.compile move the networks as
    the eager ones do (to float32 rounding: inductor sums in another order) and return the
    same losses."""
    runs = []
    for compiled in (False, True):
        torch.manual_seed(0)
        actor, critic, td = saturated_draws(0.0)
        recompute_log_prob_(actor, td, "action_log_prob")
        loss = ClipPPOLoss(actor, critic, normalize_advantage=False)
        start = torch.cat([p.detach().flatten() for p in loss.parameters()])
        optim = torch.optim.Adam(loss.parameters(), lr=1e-2)
        update = partial(ppo_step, loss, optim, max_grad_norm=0.5)
        if compiled:
            update = torch.compile(update)
        # Minibatches of one size, as the trainer's (another size would compile again).
        losses = torch.stack([update(sample.clone())["loss_objective"]
                              for sample in td.split(64)[:3]])
        runs.append((start, torch.cat([p.detach().flatten() for p in loss.parameters()]),
                     losses.detach()))
    (start, eager, eager_losses), (_, compiled, compiled_losses) = runs
    assert (eager - start).abs().max() > 1e-3  # the updates moved the networks
    torch.testing.assert_close(compiled, eager, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(compiled_losses, eager_losses, rtol=1e-4, atol=1e-5)


@pytest.mark.slow
def test_a_start_checkpoint_with_another_agent_or_a_resume_beside_it_is_refused(smoke_run,
                                                                                tmp_path):
    _, final = smoke_run
    other = load_config("smoke", ["agent.features=[goal]", f"logger.log_dir={tmp_path}"])
    with pytest.raises(ValueError, match=r"trained with another agent config: "
                                         r"agent\.features=\[\] in the checkpoint"):
        train(other, init=str(final))
    cfg = load_config("smoke", [f"logger.log_dir={tmp_path}"])
    with pytest.raises(ValueError, match="pass one of them"):
        train(cfg, resume=str(final), init=str(final))
    with pytest.raises(ValueError, match="is not a torchpark checkpoint"):
        train(cfg, init=__file__)


def test_the_gpu_preset_is_fast_at_a_gpu_size_and_reads_its_env_once_per_batch():
    """``gpu`` differs from ``fast`` in the env's size and device and the compile switches
    only: its agent, batch and minibatch are fast's (wider ones learned less in 12M frames);
    its env, resetting inside its step, holds one block of new episodes per step of a batch
    (the host reads it once a batch)."""
    import trainers.utils

    def leaves(cfg: TrainConfig) -> dict:
        flat = {}

        def walk(node: object, name: str) -> None:
            if isinstance(node, dict):
                for key, value in node.items():
                    walk(value, f"{name}.{key}".lstrip("."))
            else:
                flat[name] = node
        walk(dataclasses.asdict(cfg), "")
        return flat

    gpu = load_config("gpu", [] if torch.cuda.is_available() else ["env.device=cpu"])
    fast, ours = leaves(load_config("fast")), leaves(gpu)
    differs = {key for key in fast if fast[key] != ours[key]}
    assert differs <= {"env.num_envs", "env.device", "optim.compile_update", "logger.exp_name"}
    assert {"env.num_envs", "optim.compile_update"} <= differs
    on_cpu = dataclasses.replace(gpu, env=dataclasses.replace(gpu.env, reset_in_step=True))
    env = trainers.utils.make_base_env(on_cpu, training=False, num_envs=4)
    assert env.reset_in_step and env._resets.ring_blocks == 8 + 1  # 8 env steps per batch


def test_unknown_preset_or_field_is_an_error():
    with pytest.raises(ValueError, match="preset must be one of"):
        load_config("turbo")
    with pytest.raises(Exception, match="Key 'nope' not in 'EnvConfig'"):
        load_config("smoke", ["env.nope=1"])
    with pytest.raises(ValueError, match=r"frames_per_batch must be a multiple of env\.num_envs"):
        load_config("smoke", ["env.num_envs=7"])
    with pytest.raises(ValueError, match=r"agent\.features must be without 'slots' unless "
                                         r"agent\.aids\.observe_position is on"):
        load_config("smoke", ["agent.features=[slots]"])
    with pytest.raises(ValueError, match=r"agent\.features must be a list of distinct names "
                                         r"among goal, clearance, gear, scan_memory, slots, "
                                         r"position, brake, got \['goal', 'goal'\]"):
        load_config("smoke", ["agent.features=[goal,goal]"])


@pytest.mark.slow
def test_checkpoint_from_another_config_is_refused(smoke_run, tmp_path):
    _, final = smoke_run
    other = load_config("smoke", ["model.hidden=[32,32]", f"logger.log_dir={tmp_path}"])
    with pytest.raises(ValueError, match=r"trained with another model config: model\.hidden="
                                         r"\[64, 64\] in the checkpoint, \[32, 32\] now"):
        train(other, resume=str(final))


def test_unwritable_log_dir_is_an_error_before_training(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    cfg = load_config("smoke", [f"logger.log_dir={blocker / 'runs'}"])
    with pytest.raises(ValueError, match=r"logger\.log_dir .* cannot be created"):
        train(cfg)


@pytest.mark.slow
def test_a_run_directory_in_use_is_refused_unless_overwrite(smoke_run, capsys):
    cfg, final = smoke_run
    before = final.read_bytes()
    argv = ["--preset", "smoke", f"logger.log_dir={cfg.logger.log_dir}"]
    with pytest.raises(SystemExit) as refused:
        main(argv)
    assert refused.value.code == 2
    assert "already holds a run" in capsys.readouterr().err
    assert final.read_bytes() == before
    main([*argv, "--overwrite", "collector.total_frames=2048"])
    assert torch.load(final, weights_only=True)["frames"] == 2048
    assert not (final.parent / "checkpoint_4096.pt").exists()  # the old run's are gone
    main([*argv, "--overwrite"])  # the fixture's run, as it was, for the tests after this


@pytest.mark.slow
def test_evaluation_never_replaces_files_without_overwrite(smoke_run, tmp_path, capsys):
    _, final = smoke_run
    (tmp_path / "evaluation.md").write_text("mine")
    argv = [str(final), "--episodes", "2", "--out", str(tmp_path), "--videos", "none"]
    with pytest.raises(SystemExit) as refused:
        evaluate_main(argv)
    assert refused.value.code == 2 and "evaluation.md exists" in capsys.readouterr().err
    assert (tmp_path / "evaluation.md").read_text() == "mine"
    evaluate_main([*argv, "--overwrite"])
    assert (tmp_path / "evaluation.md").read_text().startswith("agent: policy alone")


@pytest.mark.slow
def test_evaluation_table_has_the_stated_columns(smoke_run, tmp_path):
    _, final = smoke_run
    evaluate_main([str(final), "--episodes", "6", "--out", str(tmp_path)])
    with open(tmp_path / "evaluation.csv") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == COLUMNS
    assert [float(r["occupancy"]) for r in rows] == [0.0, 0.2, 0.4, 0.6, 0.8, 0.9]
    assert [float(r["paper_success"]) for r in rows] == [0.20, 0.52, 0.65, 0.64, 0.59, 0.62]
    assert {(r["agent"], r["brake"], r["docking_law"], r["action_repeat"]) for r in rows} == {
        ("policy alone", "off", "off", "1")}  # the smoke preset: no aid
    assert all(r["policy"].startswith("PPO (smoke preset run), ") for r in rows)
    for r in rows:  # every lot's first episode ended, in exactly one way
        total = float(r["success"]) + float(r["collision"]) + float(r["timeout"])
        assert total == pytest.approx(1.0)
        assert float(r["success"]) <= float(r["success_4e-3"]) <= float(r["success_4e-2"])
        assert 1 <= float(r["mean_length"]) <= 50 and float(r["pos_err_median_m"]) >= 0
    markdown = (tmp_path / "evaluation.md").read_text()
    caption, blank, test, blank_too, header = markdown.splitlines()[:5]
    assert caption.startswith("agent: policy alone; brake: off; docking law: off; action repeat: 1")
    assert test == "collision test: the paper's, the car's box at the end of each step of dt"
    assert blank == blank_too == ""
    assert header.startswith("| occupancy | episodes | success | success_4e-3 |")
    assert markdown.count("\n") == 12
    videos = sorted(p.name for p in tmp_path.glob("rollout_occ*.mp4"))
    assert videos == [f"rollout_occ{p}.mp4" for p in sorted(["0", "20", "40", "60", "80", "90"])]
    assert iio.improps(tmp_path / "rollout_occ90.mp4").shape[1:] == (384, 480, 3)


@pytest.mark.slow
def test_evaluation_puts_a_policy_under_other_aids(smoke_run, tmp_path):
    """--aids: the smoke run's policy alone evaluated as the approach of a hybrid (brake +
    docking law), said so in the table; the same lots as without them."""
    _, final = smoke_run
    aids = ["brake.steer_clear=5", "docking.lateral=2.0", "docking.heading=1.0"]
    plain = evaluate(str(final), episodes=6, levels=(0.9,))[0]
    aided = evaluate(str(final), episodes=6, levels=(0.9,), aids=aids)[0]
    assert (plain["agent"], plain["brake"], plain["docking_law"]) == (
        "policy alone", "off", "off")
    assert aided["agent"] == ("hybrid: policy + emergency brake + docking law, added at "
                              "evaluation")
    assert aided["brake"] == "steers clear (5 angles)"
    assert aided["docking_law"] == "0-8 m behind the goal, +-2 m, +-1 rad"
    assert aided["collision"] == 0.0  # the brake stops every colliding step
    assert aided["policy"] == plain["policy"]  # the same network
    evaluate_main([str(final), "--episodes", "2", "--out", str(tmp_path), "--videos", "none",
                   "--aids", *aids])
    assert (tmp_path / "evaluation.md").read_text().startswith(
        "agent: hybrid: policy + emergency brake + docking law, added at evaluation")


@pytest.mark.slow
def test_evaluation_with_the_collision_test_along_the_motion_says_so(smoke_run, tmp_path,
                                                                    capsys):
    """--collision-substeps K evaluates the policy with K poses per step of dt tested for
    collision (the task's test is the paper's), says so in the table and on the terminal;
    a count outside [1, 64] is refused by name."""
    _, final = smoke_run
    argv = [str(final), "--episodes", "2", "--out", str(tmp_path), "--videos", "none"]
    evaluate_main([*argv, "--collision-substeps", "8"])
    line = "collision test: along the motion, 8 poses per step of dt (misses no contact " \
           "deeper than 67 mm)"
    assert line in capsys.readouterr().out.splitlines()
    assert (tmp_path / "evaluation.md").read_text().splitlines()[2] == line
    for bad in ("0", "65"):
        with pytest.raises(SystemExit) as refused:
            evaluate_main([*argv, "--overwrite", "--collision-substeps", bad])
        assert refused.value.code == 2
        assert f"--collision-substeps must be an int in [1, 64], got {bad}" in \
            capsys.readouterr().err


@pytest.mark.slow
def test_the_evaluators_output_fits_a_terminal(smoke_run, tmp_path, capsys):
    """The command line prints what the agent is made of and the main columns within 100
    columns; the full table goes to the files."""
    _, final = smoke_run
    evaluate_main([str(final), "--episodes", "2", "--out", str(tmp_path), "--videos", "none"])
    out = capsys.readouterr().out.splitlines()
    # The last line names the files, the user's own path: as long as that path is.
    assert max(len(line) for line in out if str(tmp_path) not in line) <= 100
    assert out[0].startswith("agent: policy alone") and "C < 4e-4" in out[-8]
    assert [line.split()[0] for line in out[-7:-1]] == ["0%", "20%", "40%", "60%", "80%", "90%"]
    assert out[-1] == f"every column: {tmp_path / 'evaluation.md'} (and .csv)"
    assert (tmp_path / "evaluation.md").read_text().count("|") > 17 * 7  # all 17 columns


@pytest.mark.slow
def test_a_sampled_evaluation_is_seeded_and_says_so(smoke_run, tmp_path, capsys):
    """--sample S: the actions are drawn from the policy's distribution, torch seeded with S
    at each level: the same S gives the same row, whichever levels ran before it."""
    _, final = smoke_run
    first = evaluate(str(final), episodes=6, levels=(0.0, 0.9), sample=3)
    again = evaluate(str(final), episodes=6, levels=(0.9,), sample=3)[0]
    mode = evaluate(str(final), episodes=6, levels=(0.9,))[0]
    assert first[1] == again
    assert again["actions"] == "sampled (torch seed 3)"
    assert mode["actions"] == "the mode (deterministic)"
    assert again["pos_err_median_m"] != mode["pos_err_median_m"]  # its std is e^0: it moves
    with pytest.raises(ValueError, match="sample must be None or a torch seed"):
        evaluate(str(final), episodes=2, levels=(0.9,), sample=True)
    with pytest.raises(SystemExit) as refused:
        evaluate_main([str(final), "--episodes", "2", "--out", str(tmp_path), "--videos",
                       "none", "--sample", "-1"])
    assert refused.value.code == 2
    assert "--sample must be a torch seed >= 0, got -1" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize(("aids", "message"), [
    (["observe_brake=true"], "--aids takes NAME=VALUE with NAME one of brake, docking"),
    (["action_repeat=5"], "--aids takes NAME=VALUE with NAME one of brake, docking"),
    (["docking"], "--aids takes NAME=VALUE"),
    (["brake.steer_clear=1"], "agent.aids.brake.steer_clear (BrakeConfig.steer_clear) must be 0 "
                              "or an int in [2, 1024]"),
    (["brake.steer_clear=True"], "agent.aids.brake.steer_clear: Value 'True'"),
    (["brake.stear_clear=5"], "Key 'stear_clear' not in 'BrakeConfig'"),
    (["docking.reach=nan"], "agent.aids.docking.reach (DockingConfig.reach) must be a finite "
                            "number > 0"),
    (["docking.heading=-1"], "DockingConfig.heading"),
])
def test_evaluation_refuses_bad_aids_by_name(smoke_run, tmp_path, capsys, aids, message):
    _, final = smoke_run
    with pytest.raises(SystemExit) as refused:
        evaluate_main([str(final), "--episodes", "2", "--out", str(tmp_path), "--videos",
                       "none", "--aids", *aids])
    assert refused.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "evaluation.md").exists()


@pytest.mark.slow
def test_training_aids_train_end_to_end_and_evaluate(tmp_path):
    """Every training option off the paper's path at once: held actions, the cubic speed map,
    near-goal starts, the emergency brake, a state-dependent std, a training success
    threshold, the docking layer, the brake steering clear with a margin and the policy
    seeing it, the gear head and the gear features."""
    cfg = load_config("smoke", [
        f"logger.log_dir={tmp_path}", "agent.aids.action_repeat=2",
        "agent.action_exponents=[3.0,1.0]", "agent.aids.near_goal_starts.probability=0.5",
        "agent.features=[goal,gear,brake]",
        "model.state_dependent_std=true", "collector.frames_per_batch=2048",
        "collector.total_frames=4096", "env.task.reward.success_threshold=1000.0",
        "agent.aids.brake.penalty=-1.0", "agent.aids.docking.lateral=1.0",
        "agent.aids.brake.steer_clear=5",
        "agent.gear_head=true", "agent.aids.brake.margin=0.2",
    ])
    assert env_configs(cfg, True)[1].brake.margin == env_configs(cfg, False)[1].brake.margin \
        == 0.2
    final = train(cfg)
    ckpt = torch.load(final, weights_only=True)
    assert ckpt["frames"] == 4096
    # Frames are steps of dt: 2 batches of 16 envs x 64 actions held 2 steps each.
    assert [int(v) for k, v in ckpt["env"].items() if k.endswith("frames")] == [4096]
    events = EventAccumulator(str(final.parent))
    events.Reload()
    assert events.Scalars("curriculum/success_threshold")[-1].value == 1000.0
    rows = evaluate(str(final), episodes=4, levels=(0.9,))
    assert rows[0]["collision"] == 0.0  # the brake stops every colliding step
    assert 0 < rows[0]["mean_length"] <= cfg.env.task.max_steps
    assert 0.0 <= rows[0]["docked"] <= 1.0
    assert rows[0]["brake"] == "steers clear (5 angles), keeps 0.2 m"


def test_training_aids_stay_out_of_the_evaluation_env():
    cfg = load_config("smoke", ["env.task.reward.success_threshold=0.1",
                                "agent.aids.brake.penalty=-1.0",
                                "env.task.reward.collision_penalty=-1000.0",
                                "agent.aids.near_goal_starts.probability=0.5",
                                "agent.aids.action_repeat=2", "agent.aids.docking.lateral=0.3",
                                "agent.aids.brake.steer_clear=5"])
    (training, train_aids), (evaluation, eval_aids) = env_configs(cfg, True), env_configs(cfg,
                                                                                          False)
    assert (training.reward.success_threshold, training.reward.collision_penalty,
            train_aids.brake.penalty, train_aids.near_goal_starts.probability) \
        == (0.1, -1000.0, -1.0, 0.5)
    assert evaluation == ParkingConfig(max_steps=cfg.env.task.max_steps)  # the paper's task
    assert eval_aids.near_goal_starts is None and eval_aids.brake.penalty == 0.0
    for aids in (train_aids, eval_aids):  # what the agent is stays
        assert aids.action_repeat == 2 and aids.brake.steer_clear == 5
        assert aids.docking == DockingConfig(lateral=0.3)
    paper = TrainConfig()  # the defaults: no aid
    assert env_configs(paper, True) == env_configs(paper, False) == (ParkingConfig(), None)


def test_observe_brake_appends_the_brake_flag_to_the_policy_input():
    cfg = load_config("smoke", ["agent.aids.brake={}", "agent.features=[goal,brake]",
                                "env.num_envs=64"])
    env = make_env(cfg)
    env.base_env.occupancy = 0.9
    td = env.reset()
    features = GOAL_FEATURES + env.base_env.obs_dim
    assert env.observation_spec["observation_policy"].shape == (64, features + 1)
    seen = torch.zeros(64, dtype=torch.bool)
    for _ in range(40):  # full throttle ends against something in most lots
        td = env.step(td.set("action", torch.tensor([[5.0, 0.3]]).expand(64, 2)))["next"]
        flag = td["observation_policy"][:, -1]
        assert torch.equal(flag, td["braked"][:, 0].float())
        assert torch.equal(td["braked"][:, 0], env.base_env.aid_state.braked)
        seen |= td["braked"][:, 0]
    assert seen.any()


def test_action_repeat_must_divide_the_batch():
    with pytest.raises(ValueError,
                       match=r"multiple of env.num_envs x agent.aids.action_repeat = 48"):
        load_config("smoke", ["agent.aids.action_repeat=3"])


@pytest.mark.parametrize("override, name", [
    ("optim.max_grad_norm=-1", "optim.max_grad_norm"), ("loss.ppo_epochs=0", "loss.ppo_epochs"),
    ("logger.checkpoint_every=0", "logger.checkpoint_every"), ("loss.gamma=1.5", "loss.gamma"),
    ("loss.gamma=0", "loss.gamma"), ("optim.lr=nan", "optim.lr"),
    ("model.hidden=[]", "model.hidden"), ("curriculum.levels=[0.5,2.0]", "curriculum.levels"),
    ("collector.total_frames=512", "collector.total_frames"),
    ("env.task.max_steps=0", "ParkingConfig.max_steps"),
    ("logger.exp_name=a/b", "logger.exp_name"),
    ("env.num_envs=true", "num_envs"), ("env.task.max_steps=1.5", "max_steps"),
    ("agent.gear_head=maybe", "gear_head"),
    ("agent.features=[brake]", "agent.features must be without 'brake' unless agent.aids.brake"),
    ("agent.features=[lidar]", "agent.features must be a list of distinct names"),
    ("agent.aids.brake.steer_clear=1", "BrakeConfig.steer_clear"),
    ("agent.aids.brake.margin=2", "BrakeConfig.margin"),
    ("agent.aids.brake.margni=0.2", "Key 'margni' not in 'BrakeConfig'"),
    ("agent.gear_head=true", "agent.gear_head"),
    ("loss.entropy_coef=-0.5", "loss.entropy_coef"),
    ("env.task.reward.collision_penalty=nan", "RewardConfig.collision_penalty"),
    ("env.task.reward.collision_penalty=200", "env.task.reward.collision_penalty"),
    *([] if torch.cuda.is_available() else [("env.device=cuda", "env.device")]),
    ("env.device=meta", "env.device"),
    ("agent.gear_head=2", "agent.gear_head must be true or false"),
    ("agent.aids.observe_position=2", "agent.aids.observe_position must be true or false"),
    ("env.reset_in_step=2", "env.reset_in_step must be true, false or null"),
    ("model.init_log_std=100", "model.init_log_std must be a number in [-20, 2]"),
    ("seed=4294967296", "seed must be an int in [0, 2**32)"),
    ("agent.memory_scans=65", "agent.memory_scans must be an int in [1, 64]"),
    ("agent.memory_scans=0", "agent.memory_scans must be an int in [1, 64]"),
])
def test_a_bad_training_field_is_one_line_naming_it(override, name, capsys):
    with pytest.raises(SystemExit) as refused:
        main(["--preset", "smoke", override])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and name in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def _leaf_fields(schema: type | None = None, prefix: str = ""):
    """Every leaf field's dot name, torchpark's own dataclasses in the sections included."""
    from trainers.config import TrainConfig

    hints = typing.get_type_hints(schema or TrainConfig)
    for f in dataclasses.fields(schema or TrainConfig):
        nested = [k for k in (*typing.get_args(hints[f.name]), hints[f.name])
                  if dataclasses.is_dataclass(k)]
        if nested:
            yield from _leaf_fields(nested[0], f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}"


# Free-form strings: any folder name is a valid log_dir / exp_name (exp_name's '/' is refused
# by a test above).
@pytest.mark.parametrize("key", [k for k in _leaf_fields()
                                 if k not in ("logger.log_dir", "logger.exp_name")])
def test_every_training_field_rejects_a_wrong_type_by_name(key):
    with pytest.raises(ValueError, match=rf"^{key}:? "):
        load_config("smoke", [f"{key}=not_a_value_of_its_type"])


# What a run writes survives every flag, every crash and every neighbour (torchpark.files).


def _copy_run(smoke_run, tmp_path) -> tuple[Path, dict[str, bytes]]:
    """A copy of the smoke run's directory (tmp_path/runs/smoke) and its files' bytes."""
    _, final = smoke_run
    run = tmp_path / "runs" / "smoke"
    shutil.copytree(final.parent, run)
    return run, _contents(run)


def _contents(run: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(run.iterdir()) if not p.name.startswith(".")}


def _craft(source: Path, path: Path, **sections) -> Path:
    """A copy of checkpoint ``source`` whose config sections are updated with ``sections``."""
    checkpoint = torch.load(source, weights_only=True)
    for name, fields in sections.items():
        checkpoint["config"][name] = {**checkpoint["config"][name], **fields}
    torch.save(checkpoint, path)
    return path


def _python(code: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=timeout, cwd=REPO)


REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_overwrite_deletes_nothing_before_every_check_has_passed(smoke_run, tmp_path, capsys):
    run, before = _copy_run(smoke_run, tmp_path)
    argv = ["--preset", "smoke", f"logger.log_dir={run.parent}", "--overwrite"]
    other = _craft(run / "checkpoint_final.pt", tmp_path / "other.pt",
                   model={"hidden": [32, 32]})
    for extra, message in ((["--resume", str(other)], "another model config"),
                           (["loss.gamma=2"], "loss.gamma must be"),
                           (["--init", str(other)], "another model config")):
        with pytest.raises(SystemExit) as refused:
            main([*argv, *extra])
        assert refused.value.code == 2 and message in capsys.readouterr().err
        assert _contents(run) == before  # nothing deleted
    # --init from the run's own final checkpoint: read, never deleted before it is replaced
    started = run / "checkpoint_final.pt"
    main([*argv, "--init", str(started), "collector.total_frames=2048"])
    final = torch.load(started, weights_only=True)
    assert final["frames"] == 2048 and final["started_from"] == str(started)
    assert sorted(_contents(run)) == ["checkpoint_2048.pt", "checkpoint_final.pt",
                                      next(n for n in _contents(run) if n.startswith("events"))]


@pytest.mark.slow
def test_two_runs_started_into_one_directory_the_second_is_refused(tmp_path):
    """The first run (held at its first update until the test lets it go on) keeps the
    directory; the second (started beside it, so that both import at once, and let into
    ``python -m trainers.ppo`` once the first trains) is refused by name and leaves the first
    to end whole."""
    go_on, first_trains = tmp_path / "go_on", tmp_path / "first_trains"
    first = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import pathlib, time
        import trainers.ppo as ppo

        real_step = ppo.ppo_step

        def held(*args, **kwargs):
            deadline = time.monotonic() + 120
            while not pathlib.Path({str(go_on)!r}).exists() and time.monotonic() < deadline:
                time.sleep(0.05)
            return real_step(*args, **kwargs)

        ppo.ppo_step = held
        ppo.main(["--preset", "smoke", "logger.log_dir={tmp_path}",
                  "collector.total_frames=1024"])
    """)], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    second = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import pathlib, runpy, sys, time
        import trainers.ppo

        deadline = time.monotonic() + 120
        while not pathlib.Path({str(first_trains)!r}).exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        sys.argv = ["trainers.ppo", "--preset", "smoke", "logger.log_dir={tmp_path}"]
        runpy.run_module("trainers.ppo", run_name="__main__", alter_sys=True)
    """)], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not list((tmp_path / "smoke").glob("events.out.tfevents.*")):  # it trains
            assert first.poll() is None and time.monotonic() < deadline
            time.sleep(0.1)
        first_trains.touch()
        _, second_err = second.communicate(timeout=300)
        assert first.poll() is None  # the second ended while the first still ran
        assert second.returncode == 2
        assert second_err.strip().splitlines()[-1] == (
            f"python -m trainers.ppo: error: logger.log_dir '{tmp_path / 'smoke'}' is "
            f"in use by another run (it holds .torchpark.lock): wait for it to end, or choose "
            f"another directory")
    finally:
        go_on.touch()
        if second.poll() is None:  # the test failed before the second ran
            second.kill()
            second.communicate()
        _, err = first.communicate(timeout=300)
    assert first.returncode == 0, err[-2000:]
    assert len(list((tmp_path / "smoke").glob("events.out.tfevents.*"))) == 1
    assert torch.load(tmp_path / "smoke" / "checkpoint_final.pt",
                      weights_only=True)["frames"] == 1024


@pytest.mark.slow
def test_a_run_killed_while_rewriting_its_final_checkpoint_leaves_the_previous_one(
        smoke_run, tmp_path):
    """A finished run resumed into its own directory, killed (SIGKILL) half way through
    writing its new checkpoint_final.pt: the previous one is whole and resumes."""
    run, before = _copy_run(smoke_run, tmp_path)
    final = run / "checkpoint_final.pt"
    killed = _python(f"""
        import os, pathlib, signal
        from trainers.ppo import main
        real_write = pathlib.Path.write_bytes

        def dies_half_way(self, data):
            if "checkpoint_final" not in self.name:
                return real_write(self, data)
            with open(self, "wb") as f:
                f.write(bytes(data)[:len(data) // 2])
            os.kill(os.getpid(), signal.SIGKILL)

        pathlib.Path.write_bytes = dies_half_way
        main(["--preset", "smoke", "--resume", {str(final)!r}, "logger.log_dir={run.parent}",
              "collector.total_frames=5120"])
    """)
    assert killed.returncode == -9, killed.stderr[-2000:]
    assert final.read_bytes() == before["checkpoint_final.pt"]
    main(["--preset", "smoke", "--resume", str(final), f"logger.log_dir={run.parent}",
          "collector.total_frames=5120"])
    assert torch.load(final, weights_only=True)["frames"] == 5120


@pytest.mark.slow
def test_a_full_disk_is_one_line_naming_the_file_and_leaves_nothing_half_written(tmp_path):
    limited = _python(f"""
        import resource
        resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, 64 * 1024))  # events fit
        from trainers.ppo import main
        main(["--preset", "smoke", "logger.log_dir={tmp_path}"])
    """)
    checkpoint = tmp_path / "smoke" / "checkpoint_2048.pt"
    assert limited.returncode == 2 and "Traceback" not in limited.stderr
    assert limited.stderr.strip().splitlines()[-1] == (
        f"python -m trainers.ppo: error: cannot write {str(checkpoint)!r}: File too large")
    assert sorted(p.name for p in (tmp_path / "smoke").iterdir()
                  if not p.name.startswith("events")) == [".torchpark.lock"]


@pytest.mark.slow
def test_the_evaluator_prints_its_table_before_a_full_disk_stops_its_files(smoke_run,
                                                                          tmp_path):
    _, final = smoke_run
    limited = _python(f"""
        import resource
        resource.setrlimit(resource.RLIMIT_FSIZE, (512, 512))
        from trainers.evaluate import main
        main([{str(final)!r}, "--episodes", "2", "--out", {str(tmp_path)!r}, "--videos",
              "none"])
    """)
    assert limited.returncode == 2 and "Traceback" not in limited.stderr
    lines = limited.stdout.strip().splitlines()
    assert lines[-7].split()[:3] == ["occupancy", "C", "<"]  # the summary's heading, 6 rows
    assert [line.split()[0] for line in lines[-6:]] == ["0%", "20%", "40%", "60%", "80%", "90%"]
    assert limited.stderr.strip().splitlines()[-1] == (
        f"python -m trainers.evaluate: error: cannot write "
        f"{str(tmp_path / 'evaluation.csv')!r}: File too large")
    assert [p.name for p in tmp_path.iterdir()] == [".torchpark.lock"]


@pytest.mark.slow
def test_two_evaluations_into_one_directory_the_second_is_refused(smoke_run, tmp_path, capsys):
    _, final = smoke_run
    with locked(tmp_path, "--out"):
        with pytest.raises(SystemExit) as refused:
            evaluate_main([str(final), "--episodes", "2", "--out", str(tmp_path), "--videos",
                           "none"])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and "is in use by another run" in err
    assert not (tmp_path / "evaluation.md").exists()


@pytest.mark.slow
@pytest.mark.parametrize(("sections", "message"), [
    ({"model": {"hidden": [32, 32]}}, "its actor does not fit the network its config builds"),
    ({"agent": {"gear_head": 2}}, "agent.gear_head must be true or false, got 2"),
    ({"logger": {"exp_name": "${oc.env:HOME}"}},
     "has an OmegaConf interpolation ('${...}') in config.logger.exp_name"),
])
def test_a_crafted_checkpoint_is_one_line_naming_it(smoke_run, tmp_path, capsys, sections,
                                                    message):
    _, final = smoke_run
    crafted = _craft(final, tmp_path / "crafted.pt", **sections)
    with pytest.raises(SystemExit) as refused:
        evaluate_main([str(crafted), "--episodes", "2", "--out", str(tmp_path / "eval"),
                       "--videos", "none"])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and str(crafted) in err and message in err, err
    assert not (tmp_path / "eval" / "evaluation.md").exists()


@pytest.mark.slow
def test_a_resumed_checkpoint_whose_weights_do_not_fit_its_config_is_named(smoke_run, tmp_path,
                                                                           capsys):
    _, final = smoke_run
    crafted = _craft(final, tmp_path / "crafted.pt", model={"hidden": [32, 32]})
    with pytest.raises(SystemExit) as refused:
        main(["--preset", "smoke", "--resume", str(crafted), "model.hidden=[32,32]",
              f"logger.log_dir={tmp_path}", "collector.total_frames=6144"])
    err = capsys.readouterr().err.strip().splitlines()
    assert refused.value.code == 2 and err == [
        f"python -m trainers.ppo: error: checkpoint {str(crafted)!r}: its actor does not fit "
        f"the network its config builds: Error(s) in loading state_dict for "
        f"ProbabilisticActor:"]


@pytest.mark.slow
@pytest.mark.parametrize(("argv", "message"), [
    (["--sample", str(2**70)], "--sample must be a torch seed < 2**32"),
    (["--seed", str(2**32)], "--seed must be an int in [0, 2**32)"),
    (["--episodes", str(10**9)], "--episodes must be in [1, 1000000]"),
    (["--device", "meta"], "must be a torch device such as 'cpu' or 'cuda:0', got 'meta'"),
])
def test_an_evaluation_argument_out_of_range_is_one_line(smoke_run, tmp_path, capsys, argv,
                                                        message):
    _, final = smoke_run
    with pytest.raises(SystemExit) as refused:
        evaluate_main([str(final), "--out", str(tmp_path), "--videos", "none", *argv])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and message in err and "Traceback" not in err


def test_ray_collection_without_ray_installed_is_one_line(monkeypatch):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *args: None if name == "ray" else find_spec(name, *args))
    with pytest.raises(ValueError, match=r"dist\.collectors must be direct, process or rpc: "
                                         r"ray needs Ray installed"):
        load_config("smoke", ["dist.collectors=ray", "dist.num_collectors=2",
                              "env.num_envs=16"])
