"""Frames/s of a training preset on one process, on data-parallel ranks and with collector
workers, in one run (README, "Scaling out"):

    python -m benchmarks.scaling [--preset fast] [--batches 6] [--layouts 1 2 process:2]

Each layout trains ``--batches`` batches of the preset in its own process (``python -m
trainers.ppo``, a fresh run directory) and reads the run's TensorBoard scalars: the median
over the batches after the first two (compilation, the policy's recompile) of
``time/collect_fps``, ``time/train_fps`` and ``time/fps``, and the ratio of ``time/fps`` to
the first layout's. A layout is ``K`` (``dist.world_size=K``) or ``BACKEND:M`` (one rank,
``dist.collectors=BACKEND dist.num_collectors=M``) or ``K,BACKEND:M`` (both).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from trainers.config import load_config

TAGS = ("time/collect_fps", "time/train_fps", "time/fps")


def layout_overrides(layout: str) -> list[str]:
    """The dist.* overrides of a layout string (see the module's docstring)."""
    ranks, _, collectors = layout.partition(",")
    if ":" in ranks:
        ranks, collectors = "1", ranks
    overrides = [f"dist.world_size={int(ranks)}"]
    if collectors:
        backend, count = collectors.split(":")
        overrides += [f"dist.collectors={backend}", f"dist.num_collectors={int(count)}"]
    return overrides


def measure(preset: str, batches: int, layout: str, root: Path) -> dict[str, float]:
    cfg = load_config(preset)
    frames = cfg.collector.frames_per_batch * batches
    log_dir = root / layout.replace(":", "_").replace(",", "_")
    subprocess.run([sys.executable, "-m", "trainers.ppo", "--preset", preset,
                    f"collector.total_frames={frames}", f"logger.log_dir={log_dir}",
                    f"logger.checkpoint_every={frames}", *layout_overrides(layout)],
                   check=True, timeout=1800, stdout=subprocess.DEVNULL)
    events = EventAccumulator(str(log_dir / cfg.logger.exp_name))
    events.Reload()
    return {tag: statistics.median(e.value for e in events.Scalars(tag)[2:]) for tag in TAGS}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.scaling", description=__doc__)
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--batches", type=int, default=6, help="batches per layout, >= 3")
    parser.add_argument("--layouts", nargs="+", default=["1", "2", "process:2"])
    args = parser.parse_args(argv)
    if args.batches < 3:
        parser.error(f"--batches must be >= 3 (the first two are not counted), got "
                     f"{args.batches}")
    print(f"| layout | collect frames/s | train frames/s | frames/s | / {args.layouts[0]} |")
    print("|---|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as root:
        reference = None
        for layout in args.layouts:
            fps = measure(args.preset, args.batches, layout, Path(root))
            reference = reference or fps["time/fps"]
            print(f"| {' '.join(layout_overrides(layout))} | {fps['time/collect_fps']:,.0f} | "
                  f"{fps['time/train_fps']:,.0f} | {fps['time/fps']:,.0f} | "
                  f"{fps['time/fps'] / reference:.2f} |", flush=True)


if __name__ == "__main__":
    main()
