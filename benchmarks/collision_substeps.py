"""What the collision test along the motion (``ParkingConfig.collision_substeps``) changes and
costs, beside the paper's end-pose test, in one run.

    python -m benchmarks.collision_substeps [--substeps 2 4 8 16 64] [--envs 4096]
        [--steps 200] [--occupancy 0.9] [--sizes 4096 16384] [--device cpu]

- verdicts: the paper's env driven by uniform random actions at ``--occupancy`` (episodes
  end and reset as in training); at every step, each K's verdict on the same start poses and
  actions (``torchpark.sim.step.move``) against the end pose's: the share of steps whose
  verdict K changes (all from clear to collision: K poses include the end pose), and the
  deepest contact each misses is bounded by ``ParkingConfig.collision_miss_depth``;
- cost: the compiled raw step (``ParkingEnv._step``, random actions) per K at each N, ms and
  its ratio to the end-pose step, measured in the same run (the host clock; CUDA events on
  CUDA).
"""

from __future__ import annotations

import argparse

import torch
from tensordict import TensorDict

from benchmarks.throughput import random_actions, seconds_per_call
from torchpark import ParkingConfig, ParkingEnv
from torchpark.sim.step import move
from torchpark.sim.vehicle import clamp_action


def verdict_changes(substeps: list[int], num_envs: int, steps: int, occupancy: float,
                    device: str) -> dict[int, tuple[int, int]]:
    """Per K: (steps whose verdict K changes from the end pose's, steps taken)."""
    env = ParkingEnv(num_envs, seed=0, device=device, compile_step=True)
    env.occupancy = occupancy
    td = env.reset()
    actions = random_actions(num_envs, device, steps)
    changed = {k: torch.zeros((), dtype=torch.int64, device=device) for k in substeps}
    configs = {k: ParkingConfig(collision_substeps=k) for k in substeps}
    for action in actions:
        state = env.state
        v, delta = clamp_action(action, env.config.vehicle)
        _, end_pose = move(state.pose, v, delta, state.present, env.world, env.config)
        for k, cfg in configs.items():
            _, along = move(state.pose, v, delta, state.present, env.world, cfg)
            changed[k] += (along != end_pose).sum()
        td = env.step_and_maybe_reset(td.set("action", action))[1]
    return {k: (int(c), steps * num_envs) for k, c in changed.items()}


def step_seconds(substeps: int, num_envs: int, device: str, calls: int, repeats: int
                 ) -> float:
    """Best seconds per compiled raw step with ``substeps`` poses tested per step of dt."""
    env = ParkingEnv(num_envs, seed=0, device=device, compile_step=True,
                     config=ParkingConfig(collision_substeps=substeps))
    env.occupancy = 0.5
    env.reset()
    td = TensorDict({"action": random_actions(num_envs, device, 1)[0]},
                    batch_size=[num_envs], device=device)
    for _ in range(5):  # compile, warm the caches
        env._step(td)
    return min(seconds_per_call(lambda: env._step(td), device, calls) for _ in range(repeats))


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.collision_substeps",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--substeps", type=int, nargs="+", default=[2, 4, 8, 16, 64])
    parser.add_argument("--envs", type=int, default=4096, help="envs driven for the verdicts")
    parser.add_argument("--steps", type=int, default=200, help="steps driven for the verdicts")
    parser.add_argument("--occupancy", type=float, default=0.9)
    parser.add_argument("--sizes", type=int, nargs="+", default=[4096, 16384])
    parser.add_argument("--calls", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    for k in args.substeps:  # the config names the field and its range
        ParkingConfig(collision_substeps=k)
    print(f"Verdicts: {args.envs} envs x {args.steps} steps of uniform random actions, "
          f"occupancy {args.occupancy:.0%}, the paper's env driving")
    print("| K | misses no contact deeper than | steps changed (clear -> collision) | share |")
    print("|---:|---:|---:|---:|")
    for k, (changed, total) in verdict_changes(args.substeps, args.envs, args.steps,
                                               args.occupancy, args.device).items():
        depth = ParkingConfig(collision_substeps=k).collision_miss_depth
        print(f"| {k} | {1000 * depth:.0f} mm | {changed:,} of {total:,} | "
              f"{changed / total:.2e} |")
    print(f"\nCost: compiled ParkingEnv._step, occupancy 50 %, {args.device}, best of "
          f"{args.repeats} x {args.calls} calls")
    print("| N | K | ms per step | ratio to the end-pose step |")
    print("|---:|---:|---:|---:|")
    for n in args.sizes:
        base = step_seconds(1, n, args.device, args.calls, args.repeats)
        print(f"| {n:,} | 1 (end pose) | {1000 * base:.2f} | 1.00 |", flush=True)
        for k in args.substeps:
            seconds = step_seconds(k, n, args.device, args.calls, args.repeats)
            print(f"| {n:,} | {k} | {1000 * seconds:.2f} | {seconds / base:.2f} |", flush=True)


if __name__ == "__main__":
    main()
