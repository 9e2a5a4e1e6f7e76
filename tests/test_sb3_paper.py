"""The paper's recipe on Stable-Baselines3 (trainers/sb3_paper.py): a run stopped at a
checkpoint and resumed equals the uninterrupted run exactly, and its evaluation writes the
three-threshold table with what the agent is made of."""

from __future__ import annotations

import pytest
import torch

from trainers.evaluate import COLUMNS
from trainers.sb3_paper import MODEL, STATE, evaluate, main, train


def test_a_resumed_run_equals_the_uninterrupted_one(tmp_path):
    rollout = 2048  # SB3's default n_steps: one rollout
    whole = train(tmp_path / "whole", 3 * rollout, rollout, 10**9, seed=0, resume_run=False)
    train(tmp_path / "cut", rollout, rollout, 10**9, seed=0, resume_run=False)
    assert torch.load(tmp_path / "cut" / STATE, weights_only=True)["frames"] == rollout
    resumed = train(tmp_path / "cut", 3 * rollout, rollout, 10**9, seed=0, resume_run=True)
    assert resumed.num_timesteps == whole.num_timesteps == 3 * rollout
    torch.testing.assert_close(resumed.policy.state_dict(), whole.policy.state_dict(),
                               rtol=0, atol=0)
    torch.testing.assert_close(resumed.policy.optimizer.state_dict(),
                               whole.policy.optimizer.state_dict(), rtol=0, atol=0)
    a = torch.load(tmp_path / "whole" / STATE, weights_only=True)
    b = torch.load(tmp_path / "cut" / STATE, weights_only=True)
    assert a["numpy_rng"].pop("name") == b["numpy_rng"].pop("name") == "MT19937"
    torch.testing.assert_close(a, b, rtol=0, atol=0)  # env snapshot, last obs, both RNGs


def test_the_evaluation_is_the_three_threshold_table_of_a_policy_alone(tmp_path):
    train(tmp_path, 2048, 2048, 10**9, seed=0, resume_run=False)
    assert (tmp_path / MODEL).exists()
    rows = evaluate(tmp_path, episodes=4, seed=1)
    assert [r["occupancy"] for r in rows] == [0.0, 0.2, 0.4, 0.6, 0.8, 0.9]
    assert all(tuple(r) == COLUMNS and r["agent"] == "policy alone" for r in rows)
    assert all(r["success"] <= r["success_4e-3"] <= r["success_4e-2"] for r in rows)
    assert rows[0]["policy"].startswith("PPO (Stable-Baselines3 defaults")


def test_the_command_line_refuses_what_would_hurt(tmp_path, capsys):
    def refused(*argv: str) -> str:
        with pytest.raises(SystemExit) as stop:
            main(["--out", str(tmp_path), *argv])
        assert stop.value.code == 2
        return capsys.readouterr().err

    assert "--seed must be in [0, 2**63)" in refused("--seed", "-1")
    assert "holds no whole run" in refused("--resume")
    assert "holds no whole run" in refused("--evaluate")
    (tmp_path / MODEL).write_bytes(b"not a model")
    (tmp_path / STATE).write_bytes(b"not a state")
    assert "holds a run: --resume it or --overwrite it" in refused()
    (tmp_path / "evaluation.md").write_text("mine")
    assert "holds an evaluation: --overwrite" in refused("--evaluate")
    assert (tmp_path / "evaluation.md").read_text() == "mine"
