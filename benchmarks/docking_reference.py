"""Is the paper's success test reachable at all? The docking law alone, from near-goal starts.

    python benchmarks/docking_reference.py [--envs 500] [--occupancies 0 0.9] [--no-brake]
        [--steer-clear 5]

The success test ``C < 4e-4`` asks for about 1 mm, 0.1 deg and 4 mm/s at once. This script
starts every episode in a box behind its goal (``NearGoalStarts``: up to
``back`` m back along the slot axis, ``side`` m to either side, ``heading`` rad off) and lets
the docking layer (``torchpark.aids.docking``, a fixed feedback law driving multi-point turns,
its funnel as deep as ``DockingConfig``'s default and as wide as the box) drive, in the
paper's env otherwise (no held actions; the policy's action is ignored), with the emergency
brake under it unless ``--no-brake``, steering clear over ``--steer-clear`` angles
(``BrakeConfig.steer_clear``; 0: the brake only stops). It prints per box and occupancy
the success (``C < 4e-4``), collision and braked rates of each env's first episode (1,000
steps), as a Markdown table. The law knows nothing of parked cars but what the brake does
(it turns back when stopped); without the brake its collisions are those of its own path.
"""

from __future__ import annotations

import argparse

import torch
from brake_options import add_brake_options, brake_of
from torchrl.envs import TransformedEnv

from torchpark import AidsConfig, DockingConfig, NearGoalStarts, ParkingEnv
from torchpark.runner import run_episodes

_FUNNEL = DockingConfig()
BOXES = [(1.5, 0.05, 0.05), (6.0, 0.1, 0.1), (6.0, 0.5, 0.35), (6.0, 1.0, 0.6), (6.0, 2.5, 1.6),
         (_FUNNEL.reach, _FUNNEL.lateral, _FUNNEL.heading)]  # the last: the default funnel


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=500)
    parser.add_argument("--occupancies", type=float, nargs="+", default=[0.0, 0.9])
    add_brake_options(parser)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print("| start box: back (m), side (m), heading (rad) | occupancy | success (C < 4e-4) "
          "| collision | braked |")
    print("|---|---:|---:|---:|---:|")
    for back, side, heading in BOXES:
        aids = AidsConfig(
            near_goal_starts=NearGoalStarts(probability=1.0, reach=back, lateral=side,
                                            heading=heading, candidates=32),
            docking=DockingConfig(lateral=side, heading=heading),
            brake=brake_of(args))
        for occupancy in args.occupancies:
            env = ParkingEnv(args.envs, seed=args.seed, aids=aids)
            env.occupancy = occupancy
            zeros = torch.zeros(args.envs, 2)  # ignored: every start is in the funnel
            run = run_episodes(lambda td, a=zeros: td.set("action", a), TransformedEnv(env),
                               env.config.max_steps)
            print(f"| {back}, ±{side}, ±{heading:.3g} | {occupancy:.0%} | "
                  f"{run.success.float().mean():.2f} | {run.collision.float().mean():.2f} | "
                  f"{run.braked.float().mean():.2f} |")


if __name__ == "__main__":
    main()
