"""Can a route planner drive the approach? The approach planner and the docking law, from the
paper's uniform starts.

    python benchmarks/planner_reference.py [--envs 200] [--occupancies 0 0.2 0.4 0.6 0.8 0.9]
        [--no-brake] [--steer-clear 5] [--seed 12345]
        [--law-reach 8] [--law-lateral 2] [--law-heading 1]

The lot's geometry is the same in every env and a parked car lies inside its slot, so a path
that keeps the car off every slot but its goal's is clear at every occupancy. The planner
(``torchpark.aids.planner``, ``PlannerConfig``'s defaults) computes once the cost-to-go of
such paths to each slot's lined-up approach; every step of dt it drives the arc that
descends it, until the docking law takes over (in its funnel: the planner's target, or
wider with ``--law-*``: ``PlannerConfig.law_funnel``). The
policy's action is ignored: this is an agent of two hand-written layers, a reference for
what a learned approach could reach, and a teacher whose approach needs no brake. It prints
the tables' build time and, per occupancy, the success at the three thresholds, collision,
braked (the brake stopped or steered at least once), docked and freezing rates of each env's
first episode (seed 12345 by default; the evaluator's lots are `--seed 1`), as a Markdown table.
"""

from __future__ import annotations

import argparse
import time

import torch
from brake_options import add_brake_options, brake_of
from torchrl.envs import TransformedEnv

from torchpark import (
    AidsConfig,
    DockingConfig,
    ParkingConfig,
    ParkingEnv,
    PlannerConfig,
)
from torchpark.aids.planner import build_planner, plan_control
from torchpark.runner import run_episodes
from torchpark.sim.layout import build_layout


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=200)
    parser.add_argument("--occupancies", type=float, nargs="+",
                        default=[0.0, 0.2, 0.4, 0.6, 0.8, 0.9])
    add_brake_options(parser)
    parser.add_argument("--seed", type=int, default=12345)
    for bound, unit in (("reach", "m"), ("lateral", "m"), ("heading", "rad")):
        parser.add_argument(f"--law-{bound}", type=float, default=None,
                            help=f"the docking law's funnel ({unit}; default: the planner "
                                 f"target's {bound})")
    args = parser.parse_args()
    try:
        plan = PlannerConfig(law_reach=args.law_reach, law_lateral=args.law_lateral,
                             law_heading=args.law_heading)
    except ValueError as err:
        parser.error(str(err))
    aids = AidsConfig(docking=plan.law_funnel(DockingConfig()), brake=brake_of(args))
    started = time.perf_counter()
    config = ParkingConfig()
    planner = build_planner(build_layout(config.lot, config.vehicle), config.vehicle, plan)
    built = time.perf_counter() - started
    print("| occupancy | C < 4e-4 | 4e-3 | 4e-2 | collision | braked | docked | freezing |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for occupancy in args.occupancies:
        env = ParkingEnv(args.envs, seed=args.seed, config=config, aids=aids)
        env.occupancy = occupancy

        def drive(td, env=env, planner=planner):
            state = env.state
            v, delta, _ = plan_control(planner, state.pose, state.speed, state.goal_slot)
            return td.set("action", torch.stack((v, delta), -1))

        run = run_episodes(drive, TransformedEnv(env), env.config.max_steps)
        reached = run.reached.float().mean(0).tolist()
        rates = (run.collision, run.braked, run.docked, run.freezing)
        print(f"| {occupancy:.0%} | " + " | ".join(f"{r:.3g}" for r in reached) + " | "
              + " | ".join(f"{r.float().mean():.3g}" for r in rates) + " |", flush=True)
    print(f"\nplanner tables built in {built:.0f} s")


if __name__ == "__main__":
    main()
