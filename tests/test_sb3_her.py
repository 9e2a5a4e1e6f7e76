"""The goal-conditioned baseline (trainers/sb3_her.py): SAC + HER trains on
torchpark/ParkingGoal-v0 through the paper's occupancy levels, checkpoints tensors only, and
its evaluation is the three-threshold table of a policy alone."""

from __future__ import annotations

import pytest
import torch

from trainers.evaluate import COLUMNS
from trainers.sb3_her import STATE, evaluate, main, train

# One pytest-xdist worker for the module: its run (short_run, 11 s) is made once.
pytestmark = pytest.mark.xdist_group("sb3_her")


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """1,200 frames (200 SAC updates after 1,000 random ones), a checkpoint every 600."""
    out = tmp_path_factory.mktemp("her")
    model = train(out, 1200, 600, seed=0, compile_step=False)  # the numbers compiled gives
    return out, model


@pytest.mark.slow
def test_a_run_climbs_the_levels_and_saves_its_policy(short_run):
    out, model = short_run
    state = torch.load(out / STATE, weights_only=True)
    assert state["frames"] == model.num_timesteps == 1200 and state["wall_clock_s"] > 0
    torch.testing.assert_close(state["policy"], model.policy.state_dict(), rtol=0, atol=0)
    base = model.get_env().envs[0].unwrapped.env
    assert base.occupancy == 0.9  # the last of the six levels, 200 frames each
    assert model.replay_buffer.copy_info_dict  # the reward's collision term needs the infos


@pytest.mark.slow
def test_the_evaluation_is_the_three_threshold_table_of_a_policy_alone(short_run):
    out, _ = short_run
    rows = evaluate(out, episodes=3, seed=1)
    assert [r["occupancy"] for r in rows] == [0.0, 0.2, 0.4, 0.6, 0.8, 0.9]
    assert all(tuple(r) == COLUMNS and r["agent"] == "policy alone" for r in rows)
    assert all(r["success"] <= r["success_4e-3"] <= r["success_4e-2"] for r in rows)
    assert rows[0]["policy"].startswith("SAC + HER (Stable-Baselines3")


@pytest.mark.slow
def test_the_command_line_refuses_what_would_hurt(short_run, tmp_path, capsys):
    out, _ = short_run
    for argv, message in (
            (["--out", str(out)], "holds a run: --overwrite"),
            (["--out", str(tmp_path / "none"), "--evaluate"], "holds no run"),
            (["--out", str(tmp_path), "--total-frames", "0"], "--total-frames must be >= 1"),
            (["--out", str(tmp_path), "--seed", "-1"], "--seed")):
        with pytest.raises(SystemExit):
            main(argv)
        assert message in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize(("field", "value"), [("frames", None), ("frames", "many"),
                                              ("wall_clock_s", "x")])
def test_the_evaluation_names_the_file_and_the_field_of_a_crafted_state(
        short_run, tmp_path, capsys, field, value):
    out, _ = short_run
    state = torch.load(out / STATE, weights_only=True)
    torch.save({**state, field: value}, tmp_path / STATE)
    with pytest.raises(SystemExit) as refused:
        main(["--out", str(tmp_path), "--evaluate", "--episodes", "1"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert refused.value.code == 2 and STATE in err and f"its {field} must be" in err, err


def test_an_empty_out_is_refused_by_every_command(capsys):
    from trainers.distill.cli import main as distill
    from trainers.evaluate import main as evaluator
    from trainers.plots import main as plots
    from trainers.sb3_paper import main as paper

    for command, argv in ((main, []), (paper, []), (evaluator, ["--expert", "planner"]),
                          (plots, ["results/her"]), (distill, [])):
        with pytest.raises(SystemExit) as refused:
            command([*argv, "--out", ""])
        assert refused.value.code == 2
        assert "argument --out: must name a directory, got ''" in capsys.readouterr().err
