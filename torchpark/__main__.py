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
    try:
        start = time.perf_counter()
        drive(env, 3)  # warm-up: compiles step and reset when asked
        if env.compiled:
            print(f"compiled step and reset in {time.perf_counter() - start:.1f} s")
        start = time.perf_counter()
        counts = drive(env, args.steps)
        seconds = time.perf_counter() - start
    except (torch.OutOfMemoryError, MemoryError) as err:  # an estimate is no guarantee
        parser.exit(2, f"{parser.prog}: error: --num-envs {args.num_envs} ran out of memory "
                       f"while stepping ({str(err).splitlines()[0][:120]}): ask for fewer\n")
    print(f"{args.num_envs} lots ({env.layout.num_slots} slots, {env.layout.width:.1f} m x "
          f"{env.layout.height:.1f} m), occupancy {args.occupancy}, {args.steps} steps: "
          f"{args.num_envs * args.steps / seconds:,.0f} env-steps/s through "
          f"step_and_maybe_reset")
    print(f"episodes ended: {counts['done']} (collision {counts['collision']}, "
          f"success {counts['success']}, timeout {counts['truncated']}); "
          f"mean reward per step {counts['reward'] / (args.num_envs * args.steps):.3f}")


def drive(env: ParkingEnv, steps: int) -> dict[str, float]:
    """``steps`` batched steps of uniformly random actions with auto-reset, as
    ``env.rollout`` takes them but kept in no stack (memory of one step, whatever
    ``steps``): the ended episodes' counts and the rewards' sum."""
    td = env.reset()
    totals = {key: torch.zeros((), dtype=torch.float64, device=env.device)
              for key in ("done", "collision", "success", "truncated", "reward")}
    for _ in range(steps):
        td, td_ = env.step_and_maybe_reset(env.rand_action(td))
        for key, total in totals.items():
            total += td["next", key].sum()
        td = td_
    return {key: float(t) if key == "reward" else int(t) for key, t in totals.items()}

if __name__ == "__main__":
    main()
