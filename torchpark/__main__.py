"""Roll out random policies in a batched ParkingEnv and report what happened.

    python -m torchpark --num-envs 1024 --steps 200 --occupancy 0.5 [--eager] [--device cuda]
"""

from __future__ import annotations

import argparse
import time
import warnings

import torch

from torchpark import ParkingEnv
from torchpark.config import check_seed

MAX_STEPS = 10**7  # batched steps: far beyond a demo, short of an accidental forever


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m torchpark",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=200, help="batched steps")
    parser.add_argument("--occupancy", type=float, default=0.5)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eager", action="store_true",
                        help="compile_step=False (by default the step is compiled)")
    args = parser.parse_args(argv)
    if not 1 <= args.steps <= MAX_STEPS:
        parser.error(f"--steps must be in [1, {MAX_STEPS}], got {args.steps}")

    try:
        torch.manual_seed(check_seed(args.seed, "--seed"))  # the random actions follow it
        with warnings.catch_warnings():  # said below, in one line
            warnings.simplefilter("ignore", RuntimeWarning)
            env = ParkingEnv(args.num_envs, device=args.device, seed=args.seed,
                             compile_step=not args.eager)
        env.occupancy = args.occupancy
    except (ValueError, TypeError, RuntimeError) as err:
        parser.exit(2, f"{parser.prog}: error: {str(err).splitlines()[0]}\n")
    if not args.eager and not env.compiled:
        print("no C++ compiler found (install g++ or set CXX): the step runs eager, several "
              "times slower", flush=True)
    if env.compiled:
        print("compiling the step and the reset (tens of seconds; --eager skips it) ...",
              flush=True)
    start = time.perf_counter()
    env.rollout(3, break_when_any_done=False)  # warm-up: compiles step and reset when asked
    if env.compiled:
        print(f"compiled step and reset in {time.perf_counter() - start:.1f} s")
    start = time.perf_counter()
    rollout = env.rollout(args.steps, break_when_any_done=False)  # random actions, auto-reset
    seconds = time.perf_counter() - start
    nxt = rollout["next"]
    episodes = int(nxt["done"].sum())
    print(f"{args.num_envs} lots ({env.layout.num_slots} slots, {env.layout.width:.1f} m x "
          f"{env.layout.height:.1f} m), occupancy {args.occupancy}, {args.steps} steps: "
          f"{args.num_envs * args.steps / seconds:,.0f} env-steps/s through env.rollout")
    print(f"episodes ended: {episodes} (collision {int(nxt['collision'].sum())}, "
          f"success {int(nxt['success'].sum())}, timeout {int(nxt['truncated'].sum())}); "
          f"mean reward per step {float(nxt['reward'].mean()):.3f}")


if __name__ == "__main__":
    main()
