"""A distillation's resumable state (``DIR/dagger_state.pt``): after each iteration the
student, its optimiser, the normaliser, the random generators, the env's snapshot and the
rows of ``dagger.csv``, with the config that made them. ``--resume`` checks the saved config
against the command's as a PPO run's resume does (:func:`trainers.config.differences`):
only ``dagger.iterations`` may change."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from torchpark.files import save_torch
from trainers.config import differences, dotted, has_field
from trainers.distill.aggregate import Aggregate
from trainers.distill.config import DistillConfig

# The run's state after its last finished iteration.
STATE = "dagger_state.pt"
# The fields a resumed run may change: more iterations on the same data.
FREE = ("dagger.iterations",)


def save_state(out: Path, cfg: DistillConfig, state: dict) -> None:
    """The run's state after an iteration (``state``: tensors and plain data), whole or not at
    all."""
    save_torch({"distill": dataclasses.asdict(cfg), **state}, out / STATE)


def load_state(out: Path, cfg: DistillConfig) -> dict:
    """The state a run in ``out`` saved after its last finished iteration, checked to be of
    these settings (``dagger.iterations`` aside, which may only grow), its data files
    present. Tensors and plain data only."""
    path = out / STATE
    if not path.exists():
        raise ValueError(f"--resume: {path} does not exist (no run to continue in {out})")
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
        theirs = dict(saved["distill"])
        done = int(saved["iterations_done"])
    except Exception as err:  # not a torch file, not plain data, or not this layout
        raise ValueError(f"--resume: {path} is not a distiller's state "
                         f"({type(err).__name__})") from None
    defaults = dataclasses.asdict(DistillConfig())
    gone = sorted(k for k in dotted(theirs) if not has_field(DistillConfig, k))
    if gone:
        raise ValueError(f"--resume: the run in {out} has {gone[0]}="
                         f"{dotted(theirs)[gone[0]]!r}, a setting this distiller no longer "
                         f"has (resume it at the commit that started it)")
    differ = differences(theirs, dataclasses.asdict(cfg), defaults, FREE)
    if differ:
        key, old, now = differ[0]
        raise ValueError(f"--resume: the run in {out} has {key}={old!r}, this command "
                         f"{key}={now!r} (only dagger.iterations may change)")
    if cfg.dagger.iterations < done:
        raise ValueError(f"dagger.iterations must be >= {done}, the iterations the run in "
                         f"{out} has finished, got {cfg.dagger.iterations}")
    missing = Aggregate(out).missing(done)
    if missing is not None:
        raise ValueError(f"--resume: {missing} is missing (the run's labelled data)")
    return saved
