"""Env-steps per second of the batched step (eager and compiled) against the numpy reference.

    python benchmarks/throughput.py                      # CPU, N = 1 .. 16384
    python benchmarks/throughput.py --device cuda --sizes 1024 16384 262144 1048576

Measures ``ParkingEnv._step`` (action check, the step pipeline, the output TensorDict: what a
collector calls once per batched step, without torchrl's own bookkeeping) with
``torch.utils.benchmark.Timer`` (synchronises CUDA, adapts the repeat count), and the
reference's single-env step in the same process. Prints a Markdown table and the ratios.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict
from torch.utils.benchmark import Timer

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.reference import ReferenceParkingEnv
from torchpark import ParkingEnv


def env_steps_per_second(num_envs: int, device: str, compiled: bool, occupancy: float,
                         min_time: float, repeats: int) -> list[float]:
    env = ParkingEnv(num_envs, seed=0, device=device, compile_step=compiled)
    env.occupancy = occupancy
    env.reset()
    gen = torch.Generator(device=device).manual_seed(0)
    limits = torch.tensor([5.0, 0.785], device=device)
    action = (torch.rand(num_envs, 2, generator=gen, device=device) * 2 - 1) * limits
    td = TensorDict({"action": action}, batch_size=[num_envs], device=device)
    state = env.state

    def step() -> None:
        env._step(td)
        env._state = state  # every call steps the same states: same work, no drift

    for _ in range(3):  # compile and warm up
        step()
    # Timer runs with one thread unless told otherwise.
    timer = Timer("step()", globals={"step": step}, num_threads=torch.get_num_threads())
    return [num_envs / timer.blocked_autorange(min_run_time=min_time).median
            for _ in range(repeats)]


def reference_steps_per_second(occupancy: float, seconds: float, repeats: int) -> list[float]:
    env = ParkingEnv(1, seed=0)
    env.occupancy = occupancy
    env.reset()
    rng = np.random.default_rng(0)
    ref = ReferenceParkingEnv.from_batched(env, 0)
    actions = rng.uniform([-5, -0.785], [5, 0.785], (1000, 2))
    start_pose = (ref.x, ref.y, ref.psi)
    rates = []
    for _ in range(repeats):
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            ref.step(actions[steps % 1000])
            ref.x, ref.y, ref.psi = start_pose  # same state each step, like the batched timing
            steps += 1
        rates.append(steps / (time.perf_counter() - start))
    return rates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 1024, 4096, 16384])
    parser.add_argument("--occupancy", type=float, default=0.5)
    parser.add_argument("--min-time", type=float, default=1.0, help="seconds per measurement")
    parser.add_argument("--repeats", type=int, default=3,
                        help="measurements per figure; the best is reported (the machine's "
                             "speed drifts, and noise only ever slows a run down)")
    parser.add_argument("--no-eager", action="store_true", help="skip the eager step")
    args = parser.parse_args()

    print(f"torch {torch.__version__}, {platform.processor() or platform.machine()}, "
          f"{torch.get_num_threads()} threads, device {args.device}"
          + (f" ({torch.cuda.get_device_name()})" if args.device.startswith("cuda") else ""))
    print(f"occupancy {args.occupancy}, 16 rays, {ParkingEnv(1).layout.num_slots + 4} obstacles")
    refs = reference_steps_per_second(args.occupancy, 2 * args.min_time, args.repeats)
    reference = max(refs)
    print(f"reference (numpy, one env): {reference:,.0f} steps/s (best of {spread(refs)})")
    print(f"best of {args.repeats} measurements each; the range follows in brackets\n")
    print("| N | eager env-steps/s | compiled env-steps/s | compiled / eager "
          "| compiled / reference |")
    print("|---:|---:|---:|---:|---:|")
    for n in args.sizes:
        eager = ([float("nan")] if args.no_eager else env_steps_per_second(
            n, args.device, False, args.occupancy, args.min_time, args.repeats))
        compiled = env_steps_per_second(n, args.device, True, args.occupancy, args.min_time,
                                        args.repeats)
        print(f"| {n:,} | {max(eager):,.0f} [{spread(eager)}] | {max(compiled):,.0f} "
              f"[{spread(compiled)}] | {max(compiled) / max(eager):.1f}x "
              f"| {max(compiled) / reference:,.0f}x |", flush=True)


def spread(rates: list[float]) -> str:
    return f"{min(rates):,.0f}-{max(rates):,.0f}"


if __name__ == "__main__":
    main()
