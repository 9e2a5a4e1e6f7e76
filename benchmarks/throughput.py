"""Env-steps per second of the batched env on the paths a torchrl user runs, beside the raw
step and the numpy reference, on any device.

    python -m benchmarks.throughput                      # CPU, N = 1,024 / 4,096 / 16,384
    python -m benchmarks.throughput --device cuda --sizes 16384 262144 1048576 \\
        --modes compiled cudagraphs --profile 262144 --profile-out profile.txt

Paths per N, each in the modes asked for (eager; compiled: ``compile_step=True``;
cudagraphs: compiled with ``mode="reduce-overhead"``, CUDA only):
- step: ``ParkingEnv._step`` (action check, the step, the output TensorDict: what a collector
  calls once per batched step, without torchrl's bookkeeping), each call going on from the
  last (ended rows step on unreset: the work has static shapes, whatever the state);
- step_and_maybe_reset: ``env.step_and_maybe_reset`` with uniform random actions, as
  ``env.rollout`` and the collectors call it: episodes end (mostly collisions) and the ended
  rows reset;
- rollout: ``env.rollout`` of ``--horizon`` steps with random actions, going on from the last;
  for these two paths and the collector a measurement spans at least ``DRAWS_PER_WINDOW``
  batched draws of new episodes (the env draws N at a time, every ~140 steps with random
  actions), so the figure carries their share of the cost whatever ``--calls`` is;
- collector: a torchrl ``Collector`` of the ``fast`` preset (its aids, transforms, its
  actor's architecture at its initial weights, compiled as the preset compiles it) at
  occupancy 0.5, batches of N x ``--horizon``
  env steps: **frames/s** (steps of dt, 5 per env step, as the trainer's
  ``time/collect_fps``);
- kernel: the minimal kernel of :mod:`benchmarks.kernel` (the same step, bit for bit, as the
  fastest torch code found, with no TensorDict, check, aid or reset: the floor), on the
  env's lots, going on from the last call; the step's ratio to it;
- reset: ``ParkingEnv._reset`` of a share of the rows (0.1 %, 1 %, 10 %, 100 %), ms per
  call and its ratio to one raw step, over enough calls to include the batched draws of
  the episodes handed out (their share of the cost).
``--reset-in-step on|off`` picks the env's reset path (``ParkingEnv(reset_in_step=...)``: the
reset of the ended rows inside the step's graph, or the host path; default: the device's).
Timed with CUDA events on CUDA (the host clock elsewhere) over ``--calls`` calls after a
warm-up, best of ``--repeats``. On CUDA also the peak memory per env and the host
synchronisations per call (``torch.cuda.set_sync_debug_mode``). ``--profile N`` writes a
``torch.profiler`` table of the compiled ``step_and_maybe_reset`` path at N. Prints Markdown
tables and the ratios against the raw step and the reference's single-env step, measured in
the same run.
"""

from __future__ import annotations

import argparse
import math
import platform
import time
import warnings
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict
from tqdm.auto import tqdm  # a widget in a notebook (notebooks/04)

from tests.reference import ReferenceParkingEnv  # run from the repository root (python -m)
from torchpark import ParkingEnv

MODES = {"eager": None, "compiled": {}, "cudagraphs": {"mode": "reduce-overhead"}}
PATHS = ("step", "step_and_maybe_reset", "rollout", "kernel", "collector", "reset")
RESET_SHARES = (0.001, 0.01, 0.1, 1.0)
# Batched draws of new episodes a step_and_maybe_reset, rollout or collector measurement
# spans: the best of windows shorter than the draws' period would be one without a draw.
DRAWS_PER_WINDOW = 4


RESET_IN_STEP = {"auto": None, "on": True, "off": False}


def make_env(num_envs: int, device: str, mode: str, occupancy: float,
             validate: bool, reset_in_step: str = "auto") -> ParkingEnv:
    kwargs = MODES[mode]
    env = ParkingEnv(num_envs, seed=0, device=device, compile_step=kwargs is not None,
                     compile_kwargs=kwargs, validate_actions=validate,
                     reset_in_step=RESET_IN_STEP[reset_in_step])
    env.occupancy = occupancy
    return env


def random_actions(num_envs: int, device: str, count: int = 16) -> list[torch.Tensor]:
    gen = torch.Generator(device=device).manual_seed(0)
    limits = torch.tensor([5.0, 0.785], device=device)
    return [(torch.rand(num_envs, 2, generator=gen, device=device) * 2 - 1) * limits
            for _ in range(count)]


def step_call(env: ParkingEnv, args) -> Callable[[], None]:
    """One raw step, going on from the last one's state."""
    env.reset()
    td = TensorDict({"action": random_actions(env.num_envs, env.device, 1)[0]},
                    batch_size=[env.num_envs], device=env.device)

    def call() -> None:
        env._step(td)

    return call


def step_and_maybe_reset_call(env: ParkingEnv, args) -> Callable[[], None]:
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


def steps_per_draw(env: ParkingEnv, steps: int = 64) -> float:
    """Env steps per batched draw of N new episodes (the env draws N at a time) on
    ``step_and_maybe_reset`` with random actions: N over the rows ended per step, counted
    over ``steps`` steps (read back per step: before timing, never inside it); inf if none
    ended."""
    actions = random_actions(env.num_envs, env.device)
    td, ended = env.reset(), 0
    for step in range(steps):
        out, td = env.step_and_maybe_reset(td.set("action", actions[step % len(actions)]))
        ended += int(out["next", "done"].sum())
    return env.num_envs * steps / ended if ended else math.inf


def rollout_call(env: ParkingEnv, args) -> Callable[[], None]:
    """One ``env.rollout`` of ``args.horizon`` random steps, going on from the last one."""
    td = env.reset()

    def call() -> None:
        nonlocal td
        rollout = env.rollout(args.horizon, auto_reset=False, tensordict=td,
                              break_when_any_done=False)
        td = rollout[..., -1]["next"].exclude("reward", "done", "terminated", "truncated")

    return call


def kernel_call(env: ParkingEnv, args) -> Callable[[], None]:
    """One step of the minimal kernel (:mod:`benchmarks.kernel`) on the env's lots, going on
    from the last one's state; compiled with the kernel's inductor options where the env is
    compiled (without CUDA graphs in every compiled mode), after its first steps are checked
    against the eager kernel's (:func:`check_compiled_kernel`)."""
    from benchmarks.kernel import OPTIONS, KernelState, columns, kernel_step

    env.reset()
    sim = env.state
    state = KernelState(sim.pose, sim.goal, sim.steps, sim.present.t().contiguous())
    step = partial(kernel_step, boxes=columns(env.world.obstacles), world=env.world,
                   cfg=env.config)
    if env.compiled:
        compiled = torch.compile(step, fullgraph=True, options=OPTIONS)
        check_compiled_kernel(compiled, step, state, random_actions(env.num_envs, env.device))
        step = compiled
    action = random_actions(env.num_envs, env.device, 1)[0]

    def call() -> None:
        nonlocal state
        state = step(state, action)[0]

    return call


def check_compiled_kernel(compiled: Callable, eager: Callable, state, actions) -> None:
    """The compiled kernel's steps from ``state`` are the eager kernel's (which is the env's
    step bit for bit: tests/test_benchmark_kernel.py) to the rounding of the compiled
    trigonometry, end flags equal; RuntimeError if not: no figure is timed for a kernel that
    computes another step. Checked here rather than in the test suite, where compiling the
    kernel cost 150 s on two cores for a path only this benchmark runs."""
    ours = theirs = state
    for action in actions:
        ours, *got = compiled(ours, action)
        theirs, *want = eager(theirs, action)
        for name, a, b in zip(("pose", "observation", "reward", "terminated", "truncated",
                               "cost"), (ours.pose, *got), (theirs.pose, *want), strict=True):
            same = torch.equal(a, b) if a.dtype == torch.bool else \
                torch.allclose(a, b, rtol=0.0, atol=1e-4)
            if not same:
                raise RuntimeError(f"the compiled kernel's {name} is not the eager kernel's")
        ours = theirs  # each step from the eager state: the rounding does not accumulate


def reset_call(share: float) -> Callable[[ParkingEnv, argparse.Namespace], Callable[[], None]]:
    """A reset of round(share x N) rows (at least one), the same rows each call."""

    def make(env: ParkingEnv, args) -> Callable[[], None]:
        env.reset()
        count = max(1, round(share * env.num_envs))
        gen = torch.Generator().manual_seed(1)
        rows = torch.randperm(env.num_envs, generator=gen)[:count].to(env.device)
        mask = torch.zeros(env.num_envs, 1, dtype=torch.bool, device=env.device)
        mask[rows] = True
        td = TensorDict({"_reset": mask}, batch_size=[env.num_envs], device=env.device)

        def call() -> None:
            env._reset(td)

        return call

    return make


def collector_frames(num_envs: int, device: str, mode: str, args):
    """A call that collects one batch of the ``fast`` preset's Collector, and the frames (steps
    of dt) in that batch."""
    from torchrl.collectors import Collector

    from trainers.config import PRESETS, load_config
    from trainers.utils import NORMALISED, make_ppo_models
    from trainers.utils import make_env as make_train_env

    if mode == "cudagraphs":
        raise ValueError("the fast preset compiles without CUDA graphs")
    # The preset's batch (1,024 envs x 32 actions) is no multiple of N x its action repeat
    # past N = 32,768: the batch here is N x --horizon actions.
    frames = PRESETS["fast"]().agent.aids.action_repeat * args.horizon * num_envs
    cfg = load_config("fast", [f"env.num_envs={num_envs}", f"env.device={device}",
                               f"env.compile_step={mode == 'compiled'}",
                               f"curriculum.levels=[{args.occupancy}]",
                               f"collector.frames_per_batch={frames}"])
    env = make_train_env(cfg)
    actor, _ = make_ppo_models(env.observation_spec[NORMALISED].shape[-1], env.action_spec,
                               cfg.model)
    collector = Collector(env, actor.to(device), frames_per_batch=num_envs * args.horizon,
                          total_frames=-1, device=device,
                          compile_policy=cfg.collector.compile_policy and mode != "eager")
    env.base_env.randomize_step_counts()  # as the trainer does: timeouts spread out
    batches = iter(collector)

    def call() -> None:
        next(batches)

    # Batches spanning DRAWS_PER_WINDOW draws of N episodes, from the ends of a few batches.
    probe = 4
    ended = sum(int(next(batches)["next", "done"].sum()) for _ in range(probe))
    per_draw = probe * args.horizon * num_envs / ended if ended else math.inf
    return call, frames, window(DRAWS_PER_WINDOW * per_draw, args.horizon)


CALLS = {"step": step_call, "step_and_maybe_reset": step_and_maybe_reset_call,
         "rollout": rollout_call, "kernel": kernel_call,
         **{f"reset {share:g}": reset_call(share) for share in RESET_SHARES}}


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


def timed(call: Callable[[], None], units: int, device: str, calls: int, args
          ) -> dict[str, float]:
    """Units per second of ``call`` (best and worst of ``args.repeats``) and seconds per call
    (best), after ``args.warmup`` calls."""
    for _ in range(args.warmup):  # compile, record graphs, warm the caches
        call()
    seconds = [seconds_per_call(call, device, calls) for _ in range(args.repeats)]
    result = {"rate": units / min(seconds), "low": units / max(seconds), "seconds": min(seconds)}
    if device.startswith("cuda"):
        result["syncs"] = syncs_per_call(call)
    return result


def expand_paths(paths: list[str]) -> list[str]:
    """The path names, with ``reset`` as one entry per share."""
    return [p for path in paths
            for p in ([f"reset {s:g}" for s in RESET_SHARES] if path == "reset" else [path])]


def measure(num_envs: int, device: str, mode: str, paths: list[str], args
            ) -> dict[str, dict[str, float]]:
    """Each path's figures at ``num_envs`` in ``mode``: rate (env-steps/s; frames/s for the
    collector; resets/s for a reset), low, seconds per call, and on CUDA bytes per env and
    host syncs per call. One env (one compilation) for every path but the collector."""
    cuda = device.startswith("cuda")
    torch.compiler.reset()  # every size compiled on its own, with static shapes
    if cuda:
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats()
    results: dict[str, dict[str, float]] = {}
    env_paths = [p for p in expand_paths(paths) if p != "collector"]
    try:
        env = make_env(num_envs, device, mode, args.occupancy, validate=not args.no_validate,
                       reset_in_step=args.reset_in_step) if env_paths else None
    except Exception as err:
        return {path: {"error": describe(err)} for path in expand_paths(paths)}
    # The first call of each path compiles (tens of seconds on CPU): the bar says where it is.
    bar = tqdm([*env_paths, *(["collector"] if "collector" in paths else [])],
               desc=f"N = {num_envs:,} {mode}", unit="path", leave=False)
    for path in bar:
        bar.set_postfix_str(path)
        if path == "collector":
            break
        try:
            call = CALLS[path](env, args)
            if path.startswith("reset"):
                # Calls enough to hand out every episode drawn ahead twice: the figure is
                # the reset's cost with its share of the batched draws.
                units, calls = 1, max(args.calls, math.ceil(2 / float(path.split()[1])))
            elif path in ("step_and_maybe_reset", "rollout"):
                per_call = args.horizon if path == "rollout" else 1
                units = num_envs * per_call
                calls = max(args.calls // per_call,
                            window(DRAWS_PER_WINDOW * steps_per_draw(env), per_call))
            else:
                units, calls = num_envs, args.calls
            results[path] = timed(call, units, device, calls, args)
        except Exception as err:  # a mode that cannot run here is reported, not fatal
            results[path] = {"error": describe(err)}
        if cuda and "rate" in results[path]:
            results[path]["bytes_per_env"] = torch.cuda.max_memory_allocated() / num_envs
    if "collector" in paths:
        try:
            call, frames, batches = collector_frames(num_envs, device, mode, args)
            results["collector"] = timed(call, frames, device,
                                         max(args.calls // 8, batches), args)
        except Exception as err:
            results["collector"] = {"error": describe(err)}
    bar.close()
    return results


def window(steps: float, per_call: int, most: int = 20_000) -> int:
    """Calls of ``per_call`` env steps each that cover ``steps`` env steps (at least 1, at
    most ``most`` steps' worth)."""
    return max(1, math.ceil(min(steps, most) / per_call))


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
    """torch.profiler table of the compiled ``step_and_maybe_reset`` path (after warm-up)."""
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    env = make_env(num_envs, device, "compiled", args.occupancy, validate=not args.no_validate,
                   reset_in_step=args.reset_in_step)
    call = step_and_maybe_reset_call(env, args)
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
    path.write_text(f"step_and_maybe_reset, compiled, N = {num_envs}, 20 calls\n{table}\n")
    print(f"profile of N = {num_envs:,} written to {path}")


def cell(result: dict[str, float], fmt: str = ",.0f") -> str:
    return f"{result['rate']:{fmt}} [{result['low']:{fmt}}]" if "rate" in result \
        else result["error"]


def tables(n: int, mode: str, results: dict[str, dict[str, float]], reference: float,
           cuda: bool) -> tuple[str, str]:
    """One row of the paths table and one of the resets table for N in ``mode``."""
    step = results.get("step", {})

    def ratio(path: str) -> str:
        return f"{results[path]['rate'] / step['rate']:.2f}" \
            if "rate" in results.get(path, {}) and "rate" in step else "-"

    paths = [p for p in ("step", "step_and_maybe_reset", "rollout") if p in results]
    cells = [f"{cell(results[p])} ({ratio(p)})" if p != "step" else cell(results[p])
             for p in paths]
    if "kernel" in results:
        kernel = results["kernel"]
        cells.append(f"{cell(kernel)} ({step['rate'] / kernel['rate']:.2f})"
                     if "rate" in kernel and "rate" in step else cell(kernel))
    if "collector" in results:
        cells.append(cell(results["collector"]))
    cells.append(f"{step['rate'] / reference:,.0f}x" if "rate" in step else "-")
    row = f"| {n:,} | {mode} | " + " | ".join(cells) + " |"
    if cuda and "rate" in step:
        smr = results.get("step_and_maybe_reset", {})
        row += (f" {step['bytes_per_env'] / 2**20:.4f} | {step['syncs']:.2f} / "
                + (f"{smr['syncs']:.2f} |" if "syncs" in smr else "- |"))
    resets = [p for p in results if p.startswith("reset")]
    reset_row = ""
    if resets:
        reset_row = f"| {n:,} | {mode} | " + (f"{1e3 * step['seconds']:.2f} | " if "seconds"
                                              in step else "- | ") + " | ".join(
            f"{1e3 * results[p]['seconds']:.2f} ({results[p]['seconds'] / step['seconds']:.2f})"
            if "seconds" in results[p] and "seconds" in step else results[p].get("error", "-")
            for p in resets) + " |"
    return row, reset_row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096, 16384])
    parser.add_argument("--modes", nargs="+", default=["compiled"], choices=MODES)
    parser.add_argument("--paths", nargs="+", default=list(PATHS), choices=PATHS)
    parser.add_argument("--occupancy", type=float, default=0.5)
    parser.add_argument("--calls", type=int, default=32,
                        help="env steps per measurement (step_and_maybe_reset, rollout and "
                             "the collector: at least what spans the batched draws)")
    parser.add_argument("--horizon", type=int, default=16,
                        help="env steps per rollout and per collector batch (per env)")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=3,
                        help="measurements per figure; the best is reported (the machine's "
                             "speed drifts, and noise only ever slows a run down)")
    parser.add_argument("--no-validate", action="store_true",
                        help="validate_actions=False (no host read-back of the action check)")
    parser.add_argument("--reset-in-step", choices=RESET_IN_STEP, default="auto",
                        help="ParkingEnv(reset_in_step=...): the reset of ended rows inside "
                             "the step's graph (on), the host path (off), or the env's "
                             "default for the device (auto: on for CUDA)")
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
          f" validate_actions={not args.no_validate}, reset_in_step={args.reset_in_step}")
    refs = reference_steps_per_second(args.occupancy, 2.0, args.repeats)
    reference = max(refs)
    print(f"reference (numpy, one env): {reference:,.0f} steps/s (best of {spread(refs)})")
    print(f"best of {args.repeats} measurements, the worst in brackets; a measurement of "
          f"step_and_maybe_reset, rollout or the collector spans >= {DRAWS_PER_WINDOW} batched "
          f"draws of new episodes\n")
    shown = [p for p in ("step", "step_and_maybe_reset", "rollout") if p in args.paths]
    columns = [f"{p} env-steps/s" + ("" if p == "step" else " (/ step)") for p in shown]
    if "kernel" in args.paths:
        columns.append("kernel env-steps/s (step / kernel)")
    if "collector" in args.paths:
        columns.append("collector (fast preset) frames/s")
    head = ("| N | mode | " + " | ".join([*columns, "step / reference"]) + " |"
            + (" MB per env | host syncs per step / per step_and_maybe_reset |" if cuda else ""))
    head = head + "\n" + "|---" * head.count(" | ") + "|---|"
    reset_head = ("| N | mode | step ms | " + " | ".join(
        f"reset {100 * s:g} % ms (/ step)" for s in RESET_SHARES) + " |\n"
        + "|---" * (3 + len(RESET_SHARES)) + "|")
    rows, reset_rows = [], []
    for n in args.sizes:
        for mode in args.modes:
            row, reset_row = tables(n, mode, measure(n, args.device, mode, args.paths, args),
                                    reference, cuda)
            rows.append(row)
            reset_rows.append(reset_row)
            print(row, "\n" + reset_row if reset_row else "", flush=True)
    print("\n" + head + "\n" + "\n".join(rows))
    if any(reset_rows):
        print("\n" + reset_head + "\n" + "\n".join(r for r in reset_rows if r))
    if args.profile:
        profile(args.profile, args.device, args, args.profile_out)


def spread(rates: list[float]) -> str:
    return f"{min(rates):,.0f}-{max(rates):,.0f}"


if __name__ == "__main__":
    main()
