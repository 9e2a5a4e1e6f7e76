"""Checkpoints are read as data: a crafted file runs no code, a file that is not a checkpoint
says so with its path, and nothing a user has is overwritten without --overwrite."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from trainers.checkpoint import RESUME_KEYS, load_checkpoint
from trainers.evaluate import main as evaluate_main
from trainers.ppo import main as train_main


class Payload:
    """Unpickling this touches ``marker``: what a malicious checkpoint would do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


@pytest.fixture
def payload_checkpoint(tmp_path) -> tuple[Path, Path]:
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pt"
    torch.save({"config": {}, "frames": 0, "actor": Payload(marker), "obs_norm": {}}, path)
    return path, marker


def test_a_payload_checkpoint_runs_no_code(payload_checkpoint, tmp_path, capsys):
    path, marker = payload_checkpoint
    with pytest.raises(ValueError, match=f"checkpoint '{path}' is not a torchpark checkpoint"):
        load_checkpoint(path)
    with pytest.raises(SystemExit) as exit_eval:
        evaluate_main([str(path), "--out", str(tmp_path / "eval"), "--videos", "none"])
    with pytest.raises(SystemExit) as exit_train:
        train_main(["--preset", "smoke", "--resume", str(path),
                    f"logger.log_dir={tmp_path / 'runs'}"])
    assert exit_eval.value.code == exit_train.value.code == 2
    assert not marker.exists()
    err = capsys.readouterr().err
    assert err.count("is not a torchpark checkpoint") == 2 and "Traceback" not in err


@pytest.mark.parametrize("content", [b"# README\nnot a checkpoint\n", b"PK\x03\x04trunc", b"",
                                     b"junk\n"],
                         ids=["text", "truncated-zip", "empty", "a legacy unpickler's key"])
def test_a_file_that_is_not_a_checkpoint_names_its_path(tmp_path, content):
    path = tmp_path / "model.pt"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=f"checkpoint '{path}' is not a torchpark checkpoint"):
        load_checkpoint(path)


def test_a_truncated_checkpoint_and_a_foreign_dict_are_refused(tmp_path):
    whole = tmp_path / "whole.pt"
    torch.save({key: {} for key in RESUME_KEYS}, whole)
    cut = tmp_path / "cut.pt"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    with pytest.raises(ValueError, match="is not a torchpark checkpoint"):
        load_checkpoint(cut)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": torch.zeros(3)}, foreign)
    with pytest.raises(ValueError, match=r"lacks \['actor', 'config', 'frames', 'obs_norm'\]"):
        load_checkpoint(foreign)
    with pytest.raises(ValueError, match=r"lacks \['critic', 'env', 'optim'\]"):
        load_checkpoint(_evaluation_only(tmp_path), required=RESUME_KEYS)
    with pytest.raises(ValueError, match="is not a file"):
        load_checkpoint(tmp_path / "missing.pt")


def _evaluation_only(tmp_path: Path) -> Path:
    path = tmp_path / "slim.pt"
    torch.save({"config": {}, "frames": 0, "actor": {}, "obs_norm": {}}, path)
    return path


COMMITTED = Path(__file__).resolve().parents[1] / "results" / "fast" / "checkpoint_final.pt"


def test_the_committed_checkpoint_differs_from_its_preset_only_where_a_run_changes_it():
    """The committed ``fast`` checkpoint against the preset it was trained with differs in
    nothing; a run that changes a field is told so by name."""
    from trainers.config import load_config
    from trainers.runs import MODEL_SECTIONS, config_differences

    saved = load_checkpoint(COMMITTED)["config"]
    fast = load_config("fast")
    assert [config_differences(saved, fast, section) for section in MODEL_SECTIONS] \
        == [""] * len(MODEL_SECTIONS)
    harsher = load_config("fast", ["env.task.reward.collision_penalty=-1000.0"])
    assert config_differences(saved, harsher, "env") \
        == "env.task.reward.collision_penalty=-200.0 in the checkpoint, -1000.0 now"
