"""Env-steps per second of the batched env, raw step and collector path, against the numpy
reference, on any device.

    python -m benchmarks.throughput                      # CPU, N = 1 .. 16384
    python -m benchmarks.throughput --device cuda --sizes 1024 16384 262144 1048576 \\
        --modes eager compiled cudagraphs --profile 262144 --profile-out profile.txt

Two paths per N, each in the modes asked for (eager; compiled: ``compile_step=True``;
cudagraphs: compiled with ``mode="reduce-overhead"``, CUDA only):
- step: ``ParkingEnv._step`` (action check, the step pipeline, the output TensorDict: what a
  collector calls once per batched step, without torchrl's bookkeeping), each call going on
  from the last (ended rows step on unreset: the work has static shapes, whatever the state);
- collector: ``env.step_and_maybe_reset`` with uniform random actions, as a collector or
  ``env.rollout`` calls it: episodes end (mostly collisions) and the ended rows reset.
Timed with CUDA events on CUDA (the host clock elsewhere) over ``--calls`` calls after a
warm-up, best of ``--repeats``. On CUDA also the peak memory per env and the host
synchronisations per call (``torch.cuda.set_sync_debug_mode``). ``--profile N`` writes a
``torch.profiler`` table of the compiled collector path at N. Prints Markdown tables and
the ratios against the reference's single-env step, measured in the same run.
"""

from __future__ import annotations

import argparse
import platform
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict

from tests.reference import ReferenceParkingEnv  # run from the repository root (python -m)
from torchpark import ParkingEnv

MODES = {"eager": None, "compiled": {}, "cudagraphs": {"mode": "reduce-overhead"}}


def make_env(num_envs: int, device: str, mode: str, occupancy: float,
             validate: bool) -> ParkingEnv:
    kwargs = MODES[mode]
    env = ParkingEnv(num_envs, seed=0, device=device, compile_step=kwargs is not None,
                     compile_kwargs=kwargs, validate_actions=validate)
    env.occupancy = occupancy
    return env


def random_actions(num_envs: int, device: str, count: int = 16) -> list[torch.Tensor]:
    gen = torch.Generator(device=device).manual_seed(0)
    limits = torch.tensor([5.0, 0.785], device=device)
    return [(torch.rand(num_envs, 2, generator=gen, device=device) * 2 - 1) * limits
            for _ in range(count)]


def step_call(env: ParkingEnv) -> Callable[[], None]:
    """One raw step, going on from the last one's state."""
    env.reset()
    td = TensorDict({"action": random_actions(env.num_envs, env.device, 1)[0]},
                    batch_size=[env.num_envs], device=env.device)

    def call() -> None:
        env._step(td)

    return call


def collector_call(env: ParkingEnv) -> Callable[[], None]:
    """One ``step_and_maybe_reset`` with random actions, going on from the last one."""
    actions = random_actions(env.num_envs, env.device)
    td = env.reset()
    count = 0

    def call() -> None:
        nonlocal td, count
        td.set("action", actions[count % len(actions)])
        _, td = env.step_and_maybe_reset(td)
        count += 1

    return call


def seconds_per_call(call: Callable[[], None], device: str, calls: int) -> float:
    if device.startswith("cuda"):
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        torch.cuda.synchronize()
        start.record()
        for _ in range(calls):
            call()
        end.record()
        torch.cuda.synchronize()
        return start.elapsed_time(end) / 1e3 / calls
    start_time = time.perf_counter()
    for _ in range(calls):
        call()
    return (time.perf_counter() - start_time) / calls


def syncs_per_call(call: Callable[[], None], calls: int = 8) -> float:
    """Host synchronisations per call that CUDA reports (set_sync_debug_mode)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torch.cuda.set_sync_debug_mode("warn")
        try:
            for _ in range(calls):
                call()
        finally:
            torch.cuda.set_sync_debug_mode("default")
    return sum("synchroniz" in str(w.message) for w in caught) / calls


def measure(num_envs: int, device: str, mode: str, paths: list[str], args
            ) -> dict[str, dict[str, float]]:
    """Each path's figures at ``num_envs`` in ``mode``, from one env (one compilation)."""
    cuda = device.startswith("cuda")
    torch._dynamo.reset()  # every size compiled on its own, with static shapes
    if cuda:
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats()
    results = {}
    try:
        env = make_env(num_envs, device, mode, args.occupancy, validate=not args.no_validate)
    except Exception as err:
        return {path: {"error": describe(err)} for path in paths}
    for path in paths:
        try:
            call = (step_call if path == "step" else collector_call)(env)
            for _ in range(args.warmup):  # compile, record graphs, warm the caches
                call()
            rates = [num_envs / seconds_per_call(call, device, args.calls)
                     for _ in range(args.repeats)]
        except Exception as err:  # a mode that cannot run here is reported, not fatal
            results[path] = {"error": describe(err)}
            continue
        results[path] = {"rate": max(rates), "low": min(rates)}
        if cuda:
            results[path]["bytes_per_env"] = torch.cuda.max_memory_allocated() / num_envs
            results[path]["syncs"] = syncs_per_call(call)
    return results


def describe(err: Exception) -> str:
    return f"{type(err).__name__}: {str(err).splitlines()[0][:100]}" if str(err) else \
        type(err).__name__


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


def profile(num_envs: int, device: str, args, path: Path) -> None:
    """torch.profiler table of the compiled collector path (after warm-up)."""
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    env = make_env(num_envs, device, "compiled", args.occupancy, validate=not args.no_validate)
    call = collector_call(env)
    for _ in range(args.warmup):
        call()
    activities = [ProfilerActivity.CPU]
    if device.startswith("cuda"):
        activities.append(ProfilerActivity.CUDA)
        torch.cuda.synchronize()
    with torch_profile(activities=activities) as prof:
        for _ in range(20):
            call()
        if device.startswith("cuda"):
            torch.cuda.synchronize()
    sort = "cuda_time_total" if device.startswith("cuda") else "cpu_time_total"
    table = prof.key_averages().table(sort_by=sort, row_limit=25)
    path.write_text(f"collector path, compiled, N = {num_envs}, 20 calls\n{table}\n")
    print(f"profile of N = {num_envs:,} written to {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 1024, 4096, 16384])
    parser.add_argument("--modes", nargs="+", default=["eager", "compiled"], choices=MODES)
    parser.add_argument("--paths", nargs="+", default=["step", "collector"],
                        choices=("step", "collector"))
    parser.add_argument("--occupancy", type=float, default=0.5)
    parser.add_argument("--calls", type=int, default=50, help="calls per measurement")
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=3,
                        help="measurements per figure; the best is reported (the machine's "
                             "speed drifts, and noise only ever slows a run down)")
    parser.add_argument("--no-validate", action="store_true",
                        help="validate_actions=False (no host read-back of the action check)")
    parser.add_argument("--profile", type=int, default=None, metavar="N")
    parser.add_argument("--profile-out", type=Path, default=Path("profile.txt"))
    args = parser.parse_args()
    cuda = args.device.startswith("cuda")
    if "cudagraphs" in args.modes and not cuda:
        parser.error("--modes cudagraphs needs a CUDA --device")

    print(f"torch {torch.__version__}, {platform.processor() or platform.machine()}, "
          f"{torch.get_num_threads()} threads, device {args.device}"
          + (f" ({torch.cuda.get_device_name()})" if cuda else ""))
    print(f"occupancy {args.occupancy}, 16 rays, {ParkingEnv(1).layout.num_slots + 4} obstacles,"
          f" validate_actions={not args.no_validate}")
    refs = reference_steps_per_second(args.occupancy, 2.0, args.repeats)
    reference = max(refs)
    print(f"reference (numpy, one env): {reference:,.0f} steps/s (best of {spread(refs)})")
    print(f"env-steps/s, best of {args.repeats} x {args.calls} calls; the range in brackets\n")
    head = "| path | N | " + " | ".join(args.modes) + " | best / reference |"
    extra = " ms per call (best) | MB per env | host syncs per call |" if cuda else ""
    print(head + extra)
    print("|---" * (len(args.modes) + 3 + (3 if cuda else 0)) + "|")
    rows = {path: [] for path in args.paths}
    for n in args.sizes:
        results = {mode: measure(n, args.device, mode, args.paths, args) for mode in args.modes}
        for path in args.paths:
            by_mode = {mode: results[mode][path] for mode in args.modes}
            cells = [f"{r['rate']:,.0f} [{r['low']:,.0f}]" if "rate" in r else r["error"]
                     for r in by_mode.values()]
            good = [r for r in by_mode.values() if "rate" in r]
            best = max(good, key=lambda r: r["rate"]) if good else None
            row = f"| {path} | {n:,} | " + " | ".join(cells) + " | " + (
                f"{best['rate'] / reference:,.0f}x |" if best else "- |")
            if cuda and best:
                row += (f" {1e3 * n / best['rate']:.3f} | {best['bytes_per_env'] / 2**20:.4f} "
                        f"| {best['syncs']:.1f} |")
            rows[path].append(row)
            print(row, flush=True)
    rule = "|---" * (len(args.modes) + 3 + (3 if cuda else 0)) + "|"
    print("\n" + head + extra + "\n" + rule + "\n"
          + "\n".join(row for path in args.paths for row in rows[path]))
    if args.profile:
        profile(args.profile, args.device, args, args.profile_out)


def spread(rates: list[float]) -> str:
    return f"{min(rates):,.0f}-{max(rates):,.0f}"


if __name__ == "__main__":
    main()
