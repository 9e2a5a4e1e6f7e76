"""The paper's recipe on Stable-Baselines3 (trainers/sb3_paper.py): a run stopped at a
checkpoint and resumed equals the uninterrupted run exactly, and its evaluation writes the
three-threshold table with what the agent is made of. Rollouts of 512 frames (the recipe's
are 2,048: the same code on fewer frames; two of them pass the paper's 1,000-step episode, so
the runs see episodes end) and the env eager (what compiling gives, to float32 rounding:
tests/test_env.py), so that a run here takes seconds."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import textwrap
import zipfile
from functools import partial
from pathlib import Path

import cloudpickle
import pytest
import torch
from stable_baselines3 import PPO

from torchpark.files import locked
from trainers import sb3_paper
from trainers.evaluate import COLUMNS
from trainers.sb3_paper import MODEL, STATE, evaluate, main

REPO = Path(__file__).resolve().parents[1]
ROLLOUT = 512


@pytest.fixture(scope="module", autouse=True)
def short_rollouts():
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sb3_paper, "ROLLOUT", ROLLOUT)
        yield


train = partial(sb3_paper.train, compile_step=False)


@pytest.fixture(scope="module")
def one_rollout(tmp_path_factory):
    """A run of one rollout, its checkpoint written."""
    out = tmp_path_factory.mktemp("sb3")
    train(out, ROLLOUT, ROLLOUT, 10**9, seed=0, resume_run=False)
    return out


@pytest.mark.slow
def test_a_resumed_run_equals_the_uninterrupted_one(tmp_path):
    """Two rollouts at once, or one, a checkpoint, and the second resumed from it: the same
    weights, Adam state, env and random states."""
    rollout = ROLLOUT
    run = partial(train, frames_per_level=rollout, every=10**9, seed=0)
    whole = run(tmp_path / "whole", 2 * rollout, resume_run=False)
    run(tmp_path / "cut", rollout, resume_run=False)
    assert torch.load(tmp_path / "cut" / STATE, weights_only=True)["frames"] == rollout
    resumed = run(tmp_path / "cut", 2 * rollout, resume_run=True)
    assert resumed.num_timesteps == whole.num_timesteps == 2 * rollout
    torch.testing.assert_close(resumed.policy.state_dict(), whole.policy.state_dict(),
                               rtol=0, atol=0)
    torch.testing.assert_close(resumed.policy.optimizer.state_dict(),
                               whole.policy.optimizer.state_dict(), rtol=0, atol=0)
    a = torch.load(tmp_path / "whole" / STATE, weights_only=True)
    b = torch.load(tmp_path / "cut" / STATE, weights_only=True)
    assert a["numpy_rng"].pop("name") == b["numpy_rng"].pop("name") == "MT19937"
    torch.testing.assert_close(a, b, rtol=0, atol=0)  # env snapshot, last obs, both RNGs


@pytest.mark.slow
def test_the_evaluation_is_the_three_threshold_table_of_a_policy_alone(one_rollout):
    assert (one_rollout / MODEL).exists()
    rows = evaluate(one_rollout, episodes=4, seed=1)
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

    assert "--seed must be an int in [0, 2**32)" in refused("--seed", "-1")
    assert "--seed must be an int in [0, 2**32)" in refused("--seed", str(2**32))
    assert "holds no whole run" in refused("--resume")
    assert "holds no whole run" in refused("--evaluate")
    (tmp_path / MODEL).write_bytes(b"not a model")
    (tmp_path / STATE).write_bytes(b"not a state")
    assert "holds a run: --resume it or --overwrite it" in refused()
    (tmp_path / "evaluation.md").write_text("mine")
    assert "holds an evaluation: --overwrite" in refused("--evaluate")
    assert (tmp_path / "evaluation.md").read_text() == "mine"


class _Payload:
    """Unpickled, it writes a marker file: what a crafted model.zip could run."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "code ran"))


@pytest.mark.slow
def test_a_crafted_model_zip_runs_no_code(one_rollout, tmp_path):
    """SB3's PPO.load unpickles the zip's serialised entries (and so runs a payload); the
    script reads its checkpoint from state.pt (weights_only) and never reads model.zip."""
    out = tmp_path / "run"
    out.mkdir()
    (out / STATE).write_bytes((one_rollout / STATE).read_bytes())
    marker = tmp_path / "marker"
    crafted_zip = tmp_path / "crafted.zip"
    with zipfile.ZipFile(one_rollout / MODEL) as source, \
            zipfile.ZipFile(crafted_zip, "w") as crafted:
        for item in source.infolist():
            content = source.read(item)
            if item.filename == "data":
                data = json.loads(content)
                data["clip_range"] = {":type:": "<class 'function'>", ":serialized:":
                                      base64.b64encode(cloudpickle.dumps(_Payload(marker)))
                                      .decode()}
                content = json.dumps(data).encode()
            crafted.writestr(item, content)
    (out / MODEL).write_bytes(crafted_zip.read_bytes())
    main(["--out", str(out), "--evaluate", "--episodes", "1"])
    main(["--out", str(out), "--resume", "--total-frames", str(2 * ROLLOUT), "--eager"])
    assert not marker.exists()
    assert torch.load(out / STATE, weights_only=True)["frames"] == 2 * ROLLOUT
    PPO.load(crafted_zip, device="cpu")
    assert marker.read_text() == "code ran"  # SB3's own loader runs it: the test can fail


@pytest.mark.slow
def test_a_run_killed_while_saving_resumes_from_the_previous_checkpoint(one_rollout,
                                                                         tmp_path):
    """SIGKILL half way through writing state.pt, then half way through the model.zip export
    after it: both times --resume goes on from a whole checkpoint."""
    out = tmp_path / "run"
    out.mkdir()
    for name in (STATE, MODEL):
        (out / name).write_bytes((one_rollout / name).read_bytes())
    before = (out / STATE).read_bytes()
    for dying in ("state", "model"):
        killed = subprocess.run([sys.executable, "-c", textwrap.dedent(f"""
            import os, pathlib, signal, zipfile
            from trainers import sb3_paper
            from trainers.sb3_paper import main

            sb3_paper.ROLLOUT = {ROLLOUT}

            def die():
                os.kill(os.getpid(), signal.SIGKILL)

            if {dying!r} == "state":
                def dies_half_way(self, data):
                    with open(self, "wb") as f:
                        f.write(bytes(data)[:len(data) // 2])
                    die()
                pathlib.Path.write_bytes = dies_half_way
            else:
                real_write = zipfile.ZipFile.writestr
                def dies_in_the_zip(self, *args, **kwargs):
                    real_write(self, *args, **kwargs)
                    die()
                zipfile.ZipFile.writestr = dies_in_the_zip
            main(["--out", {str(out)!r}, "--resume", "--total-frames", "{2 * ROLLOUT}",
                  "--eager"])
        """)], capture_output=True, text=True, timeout=300, cwd=REPO)
        assert killed.returncode == -9, killed.stderr[-2000:]
        if dying == "state":
            assert (out / STATE).read_bytes() == before
    main(["--out", str(out), "--resume", "--total-frames", str(2 * ROLLOUT), "--eager"])
    assert torch.load(out / STATE, weights_only=True)["frames"] == 2 * ROLLOUT


@pytest.mark.slow
def test_a_directory_in_use_is_refused(one_rollout, capsys):
    with locked(one_rollout, "--out"):
        with pytest.raises(SystemExit) as refused:
            main(["--out", str(one_rollout), "--evaluate", "--episodes", "2", "--overwrite"])
    assert refused.value.code == 2
    assert "is in use by another run" in capsys.readouterr().err
