"""Training curves (trainers.plots): a resumed run's event files, and Stable-Baselines3's."""

from __future__ import annotations

import matplotlib
import numpy as np
from torch.utils.tensorboard import SummaryWriter

from trainers.plots import plot_losses, plot_training_curves, read_scalars

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
