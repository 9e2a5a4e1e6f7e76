"""Training curves from a run's TensorBoard events: the paper's Figure 2 and the losses; or
a distillation's DAgger iterations.

    python -m trainers.plots RUN_DIR [--out DIR]

Reads the event files with TensorBoard's own ``EventAccumulator`` and draws, against frames,
mean episode reward, mean episode length and the success / collision / timeout rates, each
phase of the curriculum shaded and labelled with its occupancy (``training_curves.png``), and
the PPO loss terms (``losses.png``). A run of ``trainers.distill`` (a ``dagger.csv``, no
events) gets ``training_curves.png`` of its checks and fit loss per iteration.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from torchpark.files import directory_arg, write_file

Scalars = dict[str, tuple[np.ndarray, np.ndarray]]
LOSSES = ("loss/objective", "loss/critic", "loss/kl_approx", "loss/clip_fraction")
# Stable-Baselines3's names for the same curves (trainers.sb3_paper's run; its episode
# reward and length are means over the last 100 episodes).
SB3_TAGS = {"rollout/ep_rew_mean": "episode/reward", "rollout/ep_len_mean": "episode/length",
            "rollout/success_rate": "episode/success_rate",
            "train/policy_gradient_loss": "loss/objective", "train/value_loss": "loss/critic",
            "train/approx_kl": "loss/kl_approx", "train/clip_fraction": "loss/clip_fraction"}


def read_scalars(run_dir: str | Path) -> Scalars:
    """Every scalar tag of the event files under ``run_dir``: tag -> (frames, values).

    Files are read in the order they were written (the timestamp in their names); a run
    resumed from a checkpoint writes a new file that logs again the frames after it, so each
    file's values replace the earlier files' from its first frame on. Stable-Baselines3's
    tags are also given their torchpark names (``SB3_TAGS``)."""
    if not Path(run_dir).is_dir():
        raise FileNotFoundError(f"run_dir {str(run_dir)!r} is not a directory")
    files = sorted((f for f in Path(run_dir).rglob("events.out.tfevents.*") if f.is_file()),
                   key=lambda f: (_timestamp(f), f.name))
    if not files:
        raise FileNotFoundError(f"no TensorBoard event files under {str(run_dir)!r}")
    scalars: dict[str, list] = {}
    for file in files:
        events = EventAccumulator(str(file), size_guidance={"scalars": 0})
        try:
            events.Reload()
        except Exception as err:  # TensorBoard's readers raise their own kinds
            raise ValueError(f"{str(file)!r} is not a readable TensorBoard event file: "
                             f"{type(err).__name__}") from None
        for tag in events.Tags()["scalars"]:
            new = [(e.step, e.value) for e in events.Scalars(tag)]
            if new:
                first = min(step for step, _ in new)
                kept = [pair for pair in scalars.get(tag, []) if pair[0] < first]
                scalars[tag] = kept + new
    if not scalars:
        raise ValueError(f"the event files under {str(run_dir)!r} hold no scalars")
    out = {}
    for tag, pairs in scalars.items():
        pairs.sort()
        steps, values = zip(*pairs, strict=True)
        out[tag] = (np.asarray(steps), np.asarray(values, dtype=np.float64))
    for sb3, name in SB3_TAGS.items():
        if sb3 in out and name not in out:
            out[name] = out[sb3]
    return out


def _timestamp(file: Path) -> int:
    """The write time in an event file's name (events.out.tfevents.TIME.HOST...); 0 when it
    has none (such a file is read first)."""
    parts = file.name.split(".")
    return int(parts[3]) if len(parts) > 3 and parts[3].isdigit() else 0


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average over ``window`` points (fewer at the start)."""
    cumsum = np.cumsum(np.insert(values, 0, 0.0))
    ends = np.arange(1, len(values) + 1)
    starts = np.maximum(ends - window, 0)
    return (cumsum[ends] - cumsum[starts]) / (ends - starts)


def shade_phases(ax, scalars: Scalars) -> None:
    """Alternate shading for each curriculum phase (a change of occupancy), labelled with
    its occupancy."""
    if "curriculum/occupancy" not in scalars:
        return
    frames, occupancy = scalars["curriculum/occupancy"]
    starts = np.flatnonzero(np.diff(occupancy, prepend=-1.0))
    ends = np.append(starts[1:], len(frames) - 1)
    for k, (a, b) in enumerate(zip(starts, ends, strict=True)):
        if k % 2 == 0:
            ax.axvspan(frames[a], frames[b], color="0.92", zorder=0)
        ax.text((frames[a] + frames[b]) / 2, 1.0, f"{occupancy[a]:.0%}", ha="center",
                va="bottom", fontsize=8, transform=ax.get_xaxis_transform())


def plot_training_curves(scalars: Scalars, window: int = 10) -> Figure:
    """Reward, length and outcome rates against frames (moving average over ``window``
    logged batches), curriculum phases shaded: the paper's Figure 2."""
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True, layout="constrained")
    panels = [
        (axes[0], [("episode/reward", "mean episode reward", "C0")], None),
        (axes[1], [("episode/length", "mean episode length", "C1")], None),
        (axes[2], [("episode/success_rate", "success", "C2"),
                   ("episode/collision_rate", "collision", "C3"),
                   ("episode/timeout_rate", "timeout", "C7")], (-0.02, 1.02)),
    ]
    for ax, series, ylim in panels:
        shade_phases(ax, scalars)
        for tag, label, colour in series:
            if tag in scalars:
                frames, values = scalars[tag]
                ax.plot(frames, values, color=colour, alpha=0.2, lw=0.8)
                ax.plot(frames, smooth(values, window), color=colour, lw=1.6, label=label)
        ax.set_ylabel(series[0][1] if len(series) == 1 else "rate of ended episodes")
        if ylim:
            ax.set_ylim(*ylim)
        if ylim and ax.get_legend_handles_labels()[0]:  # a run may have logged none of them
            ax.legend(loc="center left", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("frames")
    fig.suptitle("Training (occupancy of each curriculum phase on top)")
    return fig


def plot_losses(scalars: Scalars, window: int = 10) -> Figure:
    """The PPO loss terms of the last minibatch of each batch, against frames."""
    tags = [t for t in LOSSES if t in scalars]
    fig, axes = plt.subplots(len(tags), 1, figsize=(9, 2 * len(tags)), sharex=True,
                             layout="constrained", squeeze=False)
    for ax, tag in zip(axes[:, 0], tags, strict=True):
        shade_phases(ax, scalars)
        frames, values = scalars[tag]
        ax.plot(frames, values, alpha=0.25, lw=0.8)
        ax.plot(frames, smooth(values, window), lw=1.5)
        ax.set_ylabel(tag.split("/")[1])
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("frames")
    return fig


# trainers.distill's checks after each iteration (dagger.csv): success at the paper's test and
# collisions, from the yardstick's near-goal starts and uniform starts at 0 and 90 %.
DAGGER_CHECKS = (("yardstick", "near-goal starts, empty lot", "C0"),
                 ("uniform_0", "uniform starts, empty lot", "C2"),
                 ("uniform_90", "uniform starts, 90 %", "C3"))


DAGGER_COLUMNS = ("iteration", "loss", *(f"{prefix}_{column}" for prefix, _, _ in DAGGER_CHECKS
                                          for column in ("0.0004", "collision")))


def read_dagger(path: str | Path) -> dict[str, np.ndarray]:
    """A ``dagger.csv`` as column name -> values, one per iteration; ValueError naming the
    file when it holds no iteration, lacks a column DAGGER_COLUMNS plots, or a number."""
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            missing = [c for c in DAGGER_COLUMNS if c not in (reader.fieldnames or ())]
            rows = list(reader)
    except OSError as err:
        raise ValueError(f"{str(path)!r} cannot be read: {err.strerror or err}") from None
    except (UnicodeDecodeError, csv.Error):
        raise ValueError(f"{str(path)!r} is not a trainers.distill dagger.csv: not "
                         f"text") from None
    if missing:
        raise ValueError(f"{str(path)!r} is not a trainers.distill dagger.csv: no column "
                         f"{missing[0]!r}")
    if not rows:
        raise ValueError(f"{str(path)!r} holds no iteration")
    columns = {}
    for key in DAGGER_COLUMNS:
        for row, r in enumerate(rows, start=1):
            try:
                value = float(r[key])
            except (TypeError, ValueError):
                value = math.nan
            if not math.isfinite(value):
                raise ValueError(f"{str(path)!r} holds a value that is not a number: "
                                 f"{r[key]!r} in column {key!r}, row {row} (finite numbers "
                                 f"only)")
        columns[key] = np.asarray([float(r[key]) for r in rows])
    return columns


def plot_dagger(columns: dict[str, np.ndarray]) -> Figure:
    """Success at C < 4e-4 and collisions on the distiller's checks, and the fit's loss,
    against the DAgger iteration (0: the behaviour clone)."""
    it = columns["iteration"]
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True, layout="constrained")
    for prefix, label, colour in DAGGER_CHECKS:
        axes[0].plot(it, columns[f"{prefix}_0.0004"], "o-", color=colour, label=label)
        axes[1].plot(it, columns[f"{prefix}_collision"], "o-", color=colour, label=label)
    axes[2].plot(it, columns["loss"], "o-", color="C7")
    for ax, name in zip(axes, ("success, C < 4e-4", "collision", "fit loss"), strict=True):
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    for ax in axes[:2]:
        ax.set_ylim(-0.02, 1.02)
    axes[0].legend(loc="lower right", fontsize=8)
    axes[-1].set_xlabel("DAgger iteration (from 0, as in dagger.csv)")
    axes[-1].set_xticks(it)
    fig.suptitle("Distillation: the student's checks after each iteration")
    return fig


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m trainers.plots",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("run_dir")
    parser.add_argument("--out", default=None, type=directory_arg,
                        help="directory (default: run_dir)")
    args = parser.parse_args(argv)
    matplotlib.use("Agg")  # files only (in a notebook the figures show inline instead)
    out = args.out if args.out is not None else Path(args.run_dir)
    dagger = Path(args.run_dir) / "dagger.csv"
    try:
        if dagger.is_file() and not any(Path(args.run_dir).glob("events.out.tfevents.*")):
            figures = [("training_curves.png", plot_dagger(read_dagger(dagger)))]
        else:
            scalars = read_scalars(args.run_dir)
            figures = [("training_curves.png", plot_training_curves(scalars))]
            if any(tag in scalars for tag in LOSSES):
                figures.append(("losses.png", plot_losses(scalars)))
    except (ValueError, FileNotFoundError) as err:
        parser.error(str(err).splitlines()[0])
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        parser.exit(2, f"{parser.prog}: error: --out {str(out)!r} cannot be created: "
                       f"{err.strerror or err}\n")
    try:
        for name, fig in figures:
            write_file(out / name, lambda tmp, fig=fig: fig.savefig(tmp, dpi=120))
            plt.close(fig)
            print(out / name)
    except OSError as err:
        parser.exit(2, f"{parser.prog}: error: {str(err).splitlines()[0]}\n")


if __name__ == "__main__":
    main()
