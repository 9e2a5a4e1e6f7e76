"""Stable-Baselines3 on torchpark: frames per second of SB3's own loop on the batched
``torchpark.sb3.ParkingVecEnv`` beside ``make_vec_env`` of single ``torchpark/Parking-v0``
envs (SB3's ``DummyVecEnv``), in one run.

    python -m benchmarks.sb3_speed [--sizes 8 64 256 1024] [--single 8] [--frames 32768]

Two figures per vector env: ``vec step``, env-steps/s of ``step`` with uniform random
actions in SB3's VecEnv API (what SB3's rollout calls, info dicts included); ``PPO``,
frames/s of ``PPO("MlpPolicy", env, n_steps=max(2048 // N, 1)).learn(frames)`` (SB3's
defaults otherwise: each update on ~2,048 frames, minibatch 64, 10 epochs), the whole
algorithm, its updates included. Uncompiled envs (SB3 users' default); CPU.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecEnv
from tqdm import tqdm

import torchpark  # noqa: F401  (registers torchpark/Parking-v0)
from torchpark.gym_env import ENV_ID
from torchpark.sb3 import ParkingVecEnv


def vec_steps_per_second(env: VecEnv, seconds: float) -> float:
    """Env-steps/s of ``env.step`` with uniform random actions (after a warm-up)."""
    env.reset()
    rng = np.random.default_rng(0)
    actions = lambda: rng.uniform(-1, 1, (env.num_envs, 2)).astype(np.float32)  # noqa: E731
    for _ in range(3):
        env.step(actions())
    calls, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        env.step(actions())
        calls += 1
    return calls * env.num_envs / (time.perf_counter() - start)


def ppo_frames_per_second(env: VecEnv, frames: int) -> float:
    """Frames/s of SB3's PPO learning ``frames`` frames on ``env``."""
    model = PPO("MlpPolicy", env, n_steps=max(2048 // env.num_envs, 1), seed=0, device="cpu")
    start = time.perf_counter()
    model.learn(frames)
    return model.num_timesteps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.sb3_speed",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[8, 64, 256, 1024],
                        help="lots of the batched ParkingVecEnv")
    parser.add_argument("--single", type=int, default=8,
                        help="single envs of make_vec_env (SB3's DummyVecEnv)")
    parser.add_argument("--frames", type=int, default=32768, help="frames PPO learns")
    parser.add_argument("--seconds", type=float, default=3.0, help="per vec-step figure")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {platform.machine()}, {torch.get_num_threads()} "
          f"threads; PPO on {args.frames:,} frames, updates on ~2,048")
    envs = [(f"make_vec_env, {args.single} single envs",
             lambda: make_vec_env(ENV_ID, n_envs=args.single, seed=0))]
    envs += [(f"ParkingVecEnv({n})", lambda n=n: ParkingVecEnv(n, seed=0)) for n in args.sizes]
    rows = []
    for name, make in tqdm(envs, desc="vector envs", unit="env"):
        step = vec_steps_per_second(make(), args.seconds)
        ppo = ppo_frames_per_second(make(), args.frames)
        rows.append((name, step, ppo))
    base_step, base_ppo = rows[0][1], rows[0][2]
    print("| vector env | vec step, env-steps/s (x) | PPO, frames/s (x) |")
    print("|---|---:|---:|")
    for name, step, ppo in rows:
        print(f"| {name} | {step:,.0f} ({step / base_step:.1f}x) | "
              f"{ppo:,.0f} ({ppo / base_ppo:.1f}x) |")


if __name__ == "__main__":
    main()
