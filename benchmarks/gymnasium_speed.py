"""Does the batched speed survive the Gymnasium interface? And how fast are the pictures?

    python -m benchmarks.gymnasium_speed [--sizes 1 1024] [--seconds 3] [--compiled]

For each N: env-steps/s of the torchrl ``ParkingEnv.step`` (with torchrl's own bookkeeping,
what a user loop calls) and of the Gymnasium env on top of it (``gymnasium.make`` for N = 1,
``gymnasium.make_vec`` otherwise: numpy in and out, action checks, autoreset), same process,
same random actions, episodes running into crashes and resets, best of 3 each (alternating).
Then frames/s of
``ParkingEnv.render`` (Pillow) and of writing them to MP4. Prints Markdown tables and ratios.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import gymnasium
import numpy as np
import torch

from torchpark import ENV_ID, ParkingEnv
from torchpark.media.recording import write_video


def timed(step, seconds: float) -> float:
    """Calls of ``step`` per second over about ``seconds`` (after 3 warm-up calls)."""
    for _ in range(3):
        step()
    calls, start = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        for _ in range(10):
            step()
        calls += 10
    return calls / elapsed


def actions(n: int, count: int = 64) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.uniform([-5, -0.785], [5, 0.785], (count, n, 2)).astype(np.float32)


def torchrl_speed(n: int, seconds: float, compiled: bool) -> float:
    env = ParkingEnv(n, seed=0, compile_step=compiled)
    env.occupancy = 0.5
    batch = torch.from_numpy(actions(n))
    td = env.reset()
    i = 0

    def step() -> None:
        nonlocal td, i
        td["action"] = batch[i % len(batch)]
        _, td = env.step_and_maybe_reset(td)
        i += 1

    return n * timed(step, seconds)


def gymnasium_speed(n: int, seconds: float, compiled: bool) -> float:
    kwargs = {"occupancy": 0.5, "seed": 0, "compile_step": compiled, "physical_actions": True}
    batch = actions(n)
    i = 0
    if n == 1:
        env = gymnasium.make(ENV_ID, **kwargs)
        env.reset(seed=0)

        def step() -> None:
            nonlocal i
            _, _, terminated, truncated, _ = env.step(batch[i % len(batch), 0])
            if terminated or truncated:
                env.reset()
            i += 1
    else:
        env = gymnasium.make_vec(ENV_ID, num_envs=n, **kwargs)
        env.reset(seed=0)

        def step() -> None:
            nonlocal i
            env.step(batch[i % len(batch)])
            i += 1

    return n * timed(step, seconds)


def render_speed(seconds: float) -> tuple[float, float, tuple[int, ...]]:
    env = ParkingEnv(16, seed=0)
    env.occupancy = 0.5
    env.reset()
    i = 0

    def draw() -> None:
        nonlocal i
        env.render(i % 16)
        i += 1

    fps = timed(draw, seconds)
    frames = [env.render(i % 16) for i in range(100)]
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        write_video(frames, Path(tmp) / "bench.mp4")
        mp4 = len(frames) / (time.perf_counter() - start)
    return fps, mp4, frames[0].shape


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 1024])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--compiled", action="store_true", help="compile_step=True for both")
    parser.add_argument("--repeats", type=int, default=3, help="best of, alternating the two")
    args = parser.parse_args()
    print(f"# {platform.processor() or platform.machine()}, {torch.get_num_threads()} threads, "
          f"torch {torch.__version__}, compiled={args.compiled}, occupancy 0.5\n")
    print("| N | torchrl ParkingEnv env-steps/s | Gymnasium env-steps/s | Gymnasium / torchrl |")
    print("|---:|---:|---:|---:|")
    for n in args.sizes:
        # Alternate the two, best of --repeats each: this VM's speed drifts within minutes.
        base = gym = 0.0
        for _ in range(args.repeats):
            base = max(base, torchrl_speed(n, args.seconds, args.compiled))
            gym = max(gym, gymnasium_speed(n, args.seconds, args.compiled))
        kind = "make" if n == 1 else "make_vec"
        print(f"| {n} ({kind}) | {base:,.0f} | {gym:,.0f} | {gym / base:.2f} |", flush=True)
    fps, mp4, shape = render_speed(args.seconds)
    print(f"\nrender: {fps:,.0f} frames/s ({shape[1]}x{shape[0]} px, Pillow); "
          f"MP4 writing: {mp4:,.0f} frames/s (imageio-ffmpeg)")


if __name__ == "__main__":
    main()
