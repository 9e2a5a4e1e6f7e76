"""The paper's own recipe, on the paper's own tool chain: Stable-Baselines3's PPO with its
defaults (one env, 2,048-step rollouts, minibatch 64, 10 epochs, 64x64 tanh MLPs, lr 3e-4,
gamma 0.99, GAE 0.95, clip 0.2, no observation normalisation) on ``torchpark/Parking-v0``,
the occupancy raised every 2M frames, 12M frames; then the per-level evaluation.

    python -m trainers.sb3_paper --out results/paper                 # train (hours on CPU)
    python -m trainers.sb3_paper --out results/paper --resume        # continue, exactly
    python -m trainers.sb3_paper --out results/paper --evaluate      # the three-threshold table

Why SB3 and not ``trainers.ppo --preset paper``: it is what the paper ran, and on this CPU
it is faster (single thread, compiled step: 724 frames/s against 244 for the torchrl
preset's one-env collector). The env is the paper's: no aid, uniform starts, C < 4e-4.

Checkpoints (``--checkpoint-every`` frames, at rollout boundaries) hold the SB3 model
(``model.zip``: weights and Adam state) and ``state.pt`` (tensors and numbers only: the env's
snapshot, the next observation, torch's and numpy's random states, the frame count), so that
``--resume`` goes on exactly as if the run had not stopped.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import gymnasium
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from torchrl.envs import TransformedEnv

import torchpark  # noqa: F401  (registers torchpark/Parking-v0)
from torchpark import ParkingEnv
from torchpark.curriculum import PAPER_LEVELS
from torchpark.runner import run_episodes
from trainers.evaluate import PAPER_SUCCESS, level_row, write_tables

MODEL, STATE = "model.zip", "state.pt"


def make_env(seed: int) -> gymnasium.Env:
    """The paper's env, one lot, its step compiled (the same numbers, faster)."""
    return gymnasium.make("torchpark/Parking-v0", seed=seed, compile_step=True)


def parking_env(model: PPO) -> ParkingEnv:
    """The batched ParkingEnv under the model's (vectorised, monitored) Gymnasium env."""
    return model.get_env().envs[0].unwrapped.env


class PaperSchedule(BaseCallback):
    """The occupancy curriculum (level k from k x frames_per_level frames on, for lots drawn
    at later resets), the success rate of ended episodes in TensorBoard, and checkpoints
    every ``every`` frames at rollout boundaries (where the run resumes exactly)."""

    def __init__(self, out: Path, frames_per_level: int, every: int) -> None:
        super().__init__()
        self.out, self.frames_per_level, self.every = out, frames_per_level, every
        self.successes: list[float] = []
        self.started = time.perf_counter()

    def level(self) -> float:
        return PAPER_LEVELS[min(self.num_timesteps // self.frames_per_level,
                                len(PAPER_LEVELS) - 1)]

    def _on_rollout_start(self) -> None:
        frames = self.num_timesteps
        if frames and frames % self.every < self.model.n_steps:
            save(self.model, self.out)

    def _on_step(self) -> bool:
        for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
            if done:
                self.successes.append(float(info["success"]))
        parking_env(self.model).occupancy = self.level()
        return True

    def _on_rollout_end(self) -> None:
        if self.successes:
            self.logger.record("rollout/success_rate", float(np.mean(self.successes)))
            self.successes.clear()
        self.logger.record("curriculum/occupancy", self.level())
        self.logger.record("time/wall_clock_s", time.perf_counter() - self.started)


def save(model: PPO, out: Path) -> None:
    """The model and everything else an exact resume needs (see the module's docstring),
    each written to a temporary file first and then moved into place, so that a run killed
    while saving leaves the previous checkpoint whole."""
    model.save(out / f"tmp_{MODEL}")
    torch.save({"frames": model.num_timesteps, "env": parking_env(model).snapshot(),
                "last_obs": torch.as_tensor(model._last_obs),
                "episode_starts": torch.as_tensor(model._last_episode_starts),
                "rng": torch.get_rng_state(), "numpy_rng": numpy_rng_state()},
               out / f"tmp_{STATE}")
    os.replace(out / f"tmp_{STATE}", out / STATE)
    os.replace(out / f"tmp_{MODEL}", out / MODEL)


def numpy_rng_state() -> dict:
    """numpy's global random state (SB3 shuffles its minibatches with it) as plain data."""
    name, keys, pos, has_gauss, cached = np.random.get_state()
    return {"name": name, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
            "has_gauss": int(has_gauss), "cached": float(cached)}


def set_numpy_rng_state(state: dict) -> None:
    np.random.set_state((state["name"], state["keys"].numpy().astype(np.uint32), state["pos"],
                         state["has_gauss"], state["cached"]))


def resume(out: Path, seed: int) -> PPO:
    """The model saved in ``out``, its env and random state where the run stopped."""
    state = torch.load(out / STATE, weights_only=True)
    model = PPO.load(out / MODEL, env=make_env(seed), device="cpu")
    if model.num_timesteps != state["frames"]:
        raise ValueError(f"{out}: {MODEL} holds {model.num_timesteps} frames, {STATE} "
                         f"{state['frames']}: the run stopped while saving; no exact resume")
    model.get_env().reset()  # the wrappers' order checks; the snapshot then replaces it all
    parking_env(model).restore(state["env"])
    # SB3 resets the env at learn() unless it holds the last observation: give it the saved.
    model._last_obs = state["last_obs"].numpy()
    model._last_episode_starts = state["episode_starts"].numpy()
    torch.set_rng_state(state["rng"])
    set_numpy_rng_state(state["numpy_rng"])
    return model


def train(out: Path, total: int, frames_per_level: int, every: int, seed: int,
          resume_run: bool) -> PPO:
    """Train (or go on training) the paper's agent; checkpoints and TensorBoard in ``out``."""
    if resume_run:
        model = resume(out, seed)
    else:
        model = PPO("MlpPolicy", make_env(seed), seed=seed, device="cpu",
                    tensorboard_log=str(out))
    remaining = total - model.num_timesteps
    model.learn(remaining, callback=PaperSchedule(out, frames_per_level, every),
                reset_num_timesteps=not resume_run, tb_log_name="sb3", progress_bar=True)
    save(model, out)
    return model


def evaluate(out: Path, episodes: int, seed: int) -> list[dict]:
    """The model's table: the deterministic policy, ``episodes`` lots per level, the paper's
    env, success at C < 4e-4, 4e-3 and 4e-2."""
    model = PPO.load(out / MODEL, device="cpu")
    frames = torch.load(out / STATE, weights_only=True)["frames"]
    made_of = {"agent": "policy alone", "brake": "off", "docking_law": "off",
               "action_repeat": 1, "actions": "the mode (deterministic)",
               "policy": f"PPO (Stable-Baselines3 defaults, the paper's recipe), {frames:,} "
                         f"frames"}
    rows = []
    for level in PAPER_LEVELS:
        env = ParkingEnv(episodes, seed=seed)
        env.occupancy = level
        high = env.action_spec.space.high[0]  # the Gymnasium env's [-1, 1] actions, scaled

        def policy(td, env=env, high=high):
            action, _ = model.predict(td["observation"].numpy(), deterministic=True)
            return td.set("action", torch.as_tensor(action, dtype=torch.float32) * high)

        run = run_episodes(policy, TransformedEnv(env), env.config.max_steps,
                           desc=f"occupancy {level:.0%}")
        rows.append({**made_of, **level_row(run, level),
                     "paper_success": PAPER_SUCCESS[level]})
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m trainers.sb3_paper",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/paper"))
    parser.add_argument("--total-frames", type=int, default=12_000_000)
    parser.add_argument("--frames-per-level", type=int, default=2_000_000)
    parser.add_argument("--checkpoint-every", type=int, default=204_800,
                        help="frames (rounded to whole 2,048-step rollouts)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resume", action="store_true", help="continue the run in --out")
    parser.add_argument("--overwrite", action="store_true",
                        help="start afresh in an --out that holds a run (its checkpoint is "
                             "replaced; its TensorBoard events stay beside the new run's), or "
                             "replace an evaluation there")
    parser.add_argument("--evaluate", action="store_true",
                        help="write evaluation.md/.csv for the model in --out")
    parser.add_argument("--episodes", type=int, default=200, help="per level (--evaluate)")
    args = parser.parse_args(argv)
    for name in ("total_frames", "frames_per_level", "checkpoint_every", "episodes"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1")
    if not 0 <= args.seed < 2**63:
        parser.error(f"--seed must be in [0, 2**63), got {args.seed}")
    files = [args.out / MODEL, args.out / STATE]
    held = [f for f in files if f.exists()]
    if args.evaluate or args.resume:
        if len(held) < len(files):
            parser.error(f"{args.out} holds no whole run: it needs {MODEL} and {STATE}")
    elif held and not args.overwrite:
        parser.error(f"{args.out} holds a run: --resume it or --overwrite it")
    if args.evaluate:
        tables = [args.out / "evaluation.md", args.out / "evaluation.csv"]
        if any(t.exists() for t in tables) and not args.overwrite:
            parser.error(f"{args.out} holds an evaluation: --overwrite to replace it")
        print(write_tables(evaluate(args.out, args.episodes, seed=1), args.out))
        return
    torch.set_num_threads(1)  # one core: the machine has two
    args.out.mkdir(parents=True, exist_ok=True)
    train(args.out, args.total_frames, args.frames_per_level, args.checkpoint_every,
          args.seed, args.resume)


if __name__ == "__main__":
    main()
