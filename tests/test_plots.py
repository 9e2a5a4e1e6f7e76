"""Training curves (trainers.plots): a resumed run's event files, Stable-Baselines3's, and a
distillation's dagger.csv."""

from __future__ import annotations

import csv

import matplotlib
import numpy as np
import pytest
from torch.utils.tensorboard import SummaryWriter

from trainers.plots import (
    DAGGER_CHECKS,
    main,
    plot_dagger,
    plot_losses,
    plot_training_curves,
    read_dagger,
    read_scalars,
)

matplotlib.use("Agg")


def write_events(directory, name: str, steps: range, reward: float) -> None:
    """One event file of SB3's tags in a folder of its own, renamed to ``name`` (its
    timestamp orders it)."""
    folder = directory / name.split(".")[3]
    writer = SummaryWriter(log_dir=str(folder))
    for step in steps:
        writer.add_scalar("rollout/ep_rew_mean", reward, step)
        writer.add_scalar("train/value_loss", reward, step)
        writer.add_scalar("curriculum/occupancy", 0.0 if step < 4 else 0.2, step)
    writer.close()
    (file,) = folder.glob("events.out.tfevents.*")
    file.rename(folder / name)


def test_a_resumed_runs_later_file_replaces_the_overlap(tmp_path):
    # Written out of order on purpose: the names' timestamps decide (9000 sorts after
    # 10000 as text), not the order of writing or of the folders.
    write_events(tmp_path, "events.out.tfevents.10000.host.2.0", range(3, 7), 2.0)
    write_events(tmp_path, "events.out.tfevents.9000.host.1.0", range(0, 5), 1.0)
    scalars = read_scalars(tmp_path)
    steps, values = scalars["rollout/ep_rew_mean"]
    assert steps.tolist() == [0, 1, 2, 3, 4, 5, 6]
    assert values.tolist() == [1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0]
    np.testing.assert_array_equal(scalars["episode/reward"][1], values)  # SB3's name mapped
    assert "loss/critic" in scalars
    assert len(plot_training_curves(scalars).axes) == 3
    assert len(plot_losses(scalars).axes) == 1


def write_dagger(path, iterations: int) -> None:
    """A dagger.csv as trainers.distill writes it: its checks rising over the iterations."""
    keys = ["iteration", "loss", *(f"{p}_{t}" for p, _, _ in DAGGER_CHECKS
                                   for t in ("0.0004", "0.004", "0.04", "collision"))]
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        for i in range(iterations):
            writer.writerow({k: i if k == "iteration" else (i + 1) / (iterations + 1)
                             for k in keys})


def test_a_distillation_gets_its_checks_per_iteration(tmp_path):
    write_dagger(tmp_path / "dagger.csv", 4)
    columns = read_dagger(tmp_path / "dagger.csv")
    np.testing.assert_array_equal(columns["iteration"], [0, 1, 2, 3])
    fig = plot_dagger(columns)
    success, collision, loss = fig.axes
    assert [line.get_label() for line in success.get_lines()] == [
        label for _, label, _ in DAGGER_CHECKS]
    np.testing.assert_allclose(collision.get_lines()[2].get_ydata(), [0.2, 0.4, 0.6, 0.8])
    assert len(loss.get_lines()) == 1
    main([str(tmp_path)])  # a run folder with a dagger.csv and no events: its curves
    assert (tmp_path / "training_curves.png").stat().st_size > 10_000
    assert not (tmp_path / "losses.png").exists()  # no PPO losses in a distillation


def test_an_empty_dagger_csv_is_an_error_naming_it(tmp_path):
    write_dagger(tmp_path / "dagger.csv", 0)
    with pytest.raises(ValueError, match=r"dagger\.csv' holds no iteration"):
        read_dagger(tmp_path / "dagger.csv")


@pytest.mark.parametrize(("text", "message"), [
    ("occupancy,success\n0.0,0.5\n", "is not a trainers.distill dagger.csv: no column 'iteration'"),
    ("\x00\x01binary", "is not a trainers.distill dagger.csv"),
    (b"\xff\xfe\x00", "is not a trainers.distill dagger.csv: not text"),
])
def test_a_file_that_is_no_dagger_csv_is_refused_by_name(tmp_path, capsys, text, message):
    path = tmp_path / "dagger.csv"
    path.write_bytes(text) if isinstance(text, bytes) else path.write_text(text)
    with pytest.raises(SystemExit) as refused:
        main([str(tmp_path)])
    assert refused.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "training_curves.png").exists()


def test_a_dagger_csv_with_a_word_for_a_number_is_refused(tmp_path):
    write_dagger(tmp_path / "dagger.csv", 2)
    text = (tmp_path / "dagger.csv").read_text().replace("0.333", "many", 1)
    (tmp_path / "dagger.csv").write_text(text)
    with pytest.raises(ValueError, match="holds a value that is not a number"):
        read_dagger(tmp_path / "dagger.csv")


@pytest.mark.parametrize("word", ["nan", "inf", "-inf"])
def test_a_dagger_csv_holding_nan_is_refused_in_one_line(tmp_path, capsys, word):
    write_dagger(tmp_path / "dagger.csv", 3)
    text = (tmp_path / "dagger.csv").read_text().replace("0.5", word)
    (tmp_path / "dagger.csv").write_text(text)
    with pytest.raises(SystemExit) as refused:
        main([str(tmp_path)])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and "Traceback" not in err
    assert f"holds a value that is not a number: '{word}' in column" in err


@pytest.mark.parametrize(("make", "message"), [
    (lambda d: (d / "events.out.tfevents.not-a-time").write_text("garbage"),
     "hold no scalars"),
    (lambda d: (d / "events.out.tfevents.1.host").write_bytes(bytes(range(256)) * 4),
     "hold no scalars"),
    (lambda d: (d / "dagger.csv").mkdir(), "no TensorBoard event files under"),
    (lambda d: None, "no TensorBoard event files under"),
])
def test_a_run_directory_without_curves_is_one_line(tmp_path, capsys, make, message):
    make(tmp_path)
    with pytest.raises(SystemExit) as refused:
        main([str(tmp_path)])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and "Traceback" not in err
    assert message in err.strip().splitlines()[-1]
    assert not list(tmp_path.glob("*.png"))


def test_a_missing_run_directory_and_an_out_that_cannot_be_made_are_named(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main([str(tmp_path / "nope")])
    assert f"run_dir '{tmp_path / 'nope'}' is not a directory" in capsys.readouterr().err
    write_events(tmp_path / "run", "events.out.tfevents.100.host", range(8), 1.0)
    (tmp_path / "file").write_text("a file")
    with pytest.raises(SystemExit) as refused:
        main([str(tmp_path / "run"), "--out", str(tmp_path / "file" / "plots")])
    err = capsys.readouterr().err.strip().splitlines()
    assert refused.value.code == 2 and err[-1].startswith(
        f"python -m trainers.plots: error: --out '{tmp_path / 'file' / 'plots'}' cannot be "
        f"created")
