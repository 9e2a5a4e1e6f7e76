"""The command-line options of the reference benchmarks' emergency brake."""

from __future__ import annotations

import argparse

from torchpark import BrakeConfig


def add_brake_options(parser: argparse.ArgumentParser) -> None:
    """``--brake/--no-brake`` and ``--steer-clear N`` (the angles it tries before stopping)."""
    parser.add_argument("--brake", action=argparse.BooleanOptionalAction, default=True,
                        help="the emergency brake under the hand-written layers")
    parser.add_argument("--steer-clear", type=int, default=5,
                        help="steering angles the brake tries before stopping (0: it stops)")


def brake_of(args: argparse.Namespace) -> BrakeConfig | None:
    """The brake the options ask for, None with ``--no-brake``."""
    return BrakeConfig(steer_clear=args.steer_clear) if args.brake else None
