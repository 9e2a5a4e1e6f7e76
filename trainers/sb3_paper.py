"""The paper's own recipe, on the paper's own tool chain: Stable-Baselines3's PPO with its
defaults (one env, 2,048-step rollouts, minibatch 64, 10 epochs, 64x64 tanh MLPs, lr 3e-4,
gamma 0.99, GAE 0.95, clip 0.2, no observation normalisation) on ``torchpark/Parking-v0``,
the occupancy raised every 2M frames, 12M frames; then the per-level evaluation.

    python -m trainers.sb3_paper --out results/paper                 # train (hours on CPU)
    python -m trainers.sb3_paper --out results/paper --resume        # continue, exactly
    python -m trainers.sb3_paper --out results/paper --evaluate      # the three-threshold table

This is the one way to run the paper's recipe here (``trainers.ppo`` has no ``paper``
preset): it is what the paper ran, it made ``results/paper/``, and on this CPU it is faster
than torchrl's one-env collector (single thread, compiled step: 724 frames/s against 244).
The env is the paper's: no aid, uniform starts, C < 4e-4. It stays one Gymnasium env under
SB3's own ``DummyVecEnv`` (what ``PPO("MlpPolicy", env)`` builds), not
:class:`torchpark.sb3.ParkingVecEnv`: the adapter's gain is the batch, which the paper's one
env does not have, and ``results/paper`` was made and resumes through that wrapper (its
checkpoint holds that env's snapshot and SB3's last observation).

A checkpoint (``--checkpoint-every`` frames, at rollout boundaries) is one file,
``state.pt``, written whole or not at all (``torchpark.files``): the policy's weights and
Adam state, the env's snapshot, the next observation, torch's and numpy's random states and
the frame count, tensors and numbers only, so that ``--resume`` goes on exactly as if the
run had not stopped and a run killed at any instant leaves the previous checkpoint whole.
Beside it, ``model.zip`` is the same policy for Stable-Baselines3's ``PPO.load``, an export
this script never reads back: ``PPO.load`` unpickles (cloudpickle) entries of the zip's data,
which runs whatever code a crafted file holds, where ``torch.load(weights_only=True)`` runs
none. The run's directory is locked while it writes there (a second run is refused).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

import torchpark  # noqa: F401  (registers torchpark/Parking-v0)
from torchpark import ParkingEnv
from torchpark.curriculum import PAPER_LEVELS, level_at
from torchpark.files import directory_arg, locked, save_torch, write_file
from trainers.checkpoint import load_checkpoint, load_weights
from trainers.evaluate import evaluate_agent, evaluate_into, run_command, sb3_agent

MODEL, STATE = "model.zip", "state.pt"
ROLLOUT = 2048  # frames per rollout: SB3's default n_steps, the paper's


def make_env(seed: int, compile_step: bool = True) -> gymnasium.Env:
    """The paper's env, one lot, its step compiled (the same numbers, faster)."""
    return gymnasium.make("torchpark/Parking-v0", seed=seed, compile_step=compile_step)


def parking_env(model: BaseAlgorithm) -> ParkingEnv:
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
        return PAPER_LEVELS[level_at(self.num_timesteps, self.frames_per_level,
                                     len(PAPER_LEVELS))]

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
    """The checkpoint (see the module's docstring): ``state.pt``, then the ``model.zip``
    export, each written whole or not at all."""
    save_torch({"frames": model.num_timesteps, "updates": model._n_updates,
                "policy": model.policy.state_dict(),
                "optimizer": model.policy.optimizer.state_dict(),
                "env": parking_env(model).snapshot(),
                "last_obs": torch.as_tensor(model._last_obs),
                "episode_starts": torch.as_tensor(model._last_episode_starts),
                "rng": torch.get_rng_state(), "numpy_rng": numpy_rng_state()}, out / STATE)
    write_file(out / MODEL, model.save)


def numpy_rng_state() -> dict:
    """numpy's global random state (SB3 shuffles its minibatches with it) as plain data."""
    name, keys, pos, has_gauss, cached = np.random.get_state()
    return {"name": name, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
            "has_gauss": int(has_gauss), "cached": float(cached)}


def set_numpy_rng_state(state: dict) -> None:
    np.random.set_state((state["name"], state["keys"].numpy().astype(np.uint32), state["pos"],
                         state["has_gauss"], state["cached"]))


STATE_KEYS = frozenset({"frames", "updates", "policy", "optimizer", "env", "last_obs",
                        "episode_starts", "rng", "numpy_rng"})


def load_state(out: Path) -> dict:
    """``out/state.pt`` (``trainers.checkpoint.load_checkpoint``: tensors and plain data
    only); ValueError naming the file when it is not a whole checkpoint of this script."""
    return load_checkpoint(out / STATE, "cpu", STATE_KEYS)


def new_model(seed: int, out: Path | None = None, compile_step: bool = True) -> PPO:
    """SB3's PPO with its defaults on the paper's env (TensorBoard logs in ``out``)."""
    return PPO("MlpPolicy", make_env(seed, compile_step), n_steps=ROLLOUT, seed=seed,
               device="cpu", tensorboard_log=None if out is None else str(out))


def load_policy(model: PPO, state: dict, out: Path) -> None:
    """The checkpoint's weights and Adam state into ``model``."""
    load_weights(model.policy, state["policy"], out / STATE, "policy")
    load_weights(model.policy.optimizer, state["optimizer"], out / STATE, "optimizer")
    model.num_timesteps, model._n_updates = int(state["frames"]), int(state["updates"])


def resume(out: Path, seed: int, compile_step: bool = True) -> PPO:
    """The model saved in ``out``, its env and random state where the run stopped."""
    state = load_state(out)
    model = new_model(seed, out, compile_step)
    load_policy(model, state, out)
    model.get_env().reset()  # the wrappers' order checks; the snapshot then replaces it all
    try:
        parking_env(model).restore(state["env"])
    except (ValueError, TypeError) as err:
        raise ValueError(f"{str(out / STATE)!r}: {err}") from None
    # SB3 resets the env at learn() unless it holds the last observation: give it the saved.
    model._last_obs = state["last_obs"].numpy()
    model._last_episode_starts = state["episode_starts"].numpy()
    torch.set_rng_state(state["rng"])
    set_numpy_rng_state(state["numpy_rng"])
    return model


def train(out: Path, total: int, frames_per_level: int, every: int, seed: int,
          resume_run: bool, compile_step: bool = True) -> PPO:
    """Train (or go on training) the paper's agent; checkpoints and TensorBoard in ``out``
    (which the command line locks for the run: ``torchpark.files.locked``). ``compile_step``
    False steps the env eager: the same numbers to float32 rounding, without the compile's
    half minute, which a short run does not earn back."""
    out.mkdir(parents=True, exist_ok=True)
    model = (resume(out, seed, compile_step) if resume_run
             else new_model(seed, out, compile_step))
    remaining = total - model.num_timesteps
    model.learn(remaining, callback=PaperSchedule(out, frames_per_level, every),
                reset_num_timesteps=not resume_run, tb_log_name="sb3", progress_bar=True)
    save(model, out)
    return model


def evaluate(out: Path, episodes: int, seed: int) -> list[dict]:
    """The model's table: the deterministic policy, ``episodes`` lots per level, the paper's
    env, success at C < 4e-4, 4e-3 and 4e-2."""
    state = load_state(out)
    model = new_model(0, compile_step=False)
    load_policy(model, state, out)
    policy = (f"PPO (Stable-Baselines3 defaults, the paper's recipe), "
              f"{model.num_timesteps:,} frames")
    agent = sb3_agent(model.predict, lambda env, td: td["observation"].numpy(), policy)
    return evaluate_agent(agent, episodes, seed=seed)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m trainers.sb3_paper",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=directory_arg, default=Path("results/paper"))
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
    parser.add_argument("--eager", action="store_true",
                        help="step the env eager, not compiled (a short run: the compile "
                             "takes longer than it saves)")
    args = parser.parse_args(argv)
    run_command(parser, args,
                ("total_frames", "frames_per_level", "checkpoint_every", "episodes"), run)


def run(args: argparse.Namespace) -> None:
    """What ``main`` was asked, with the output directory locked."""
    with locked(args.out, "--out"):
        held = [f for f in (args.out / STATE, args.out / MODEL) if f.exists()]
        if (args.evaluate or args.resume) and not (args.out / STATE).exists():
            raise ValueError(f"{args.out} holds no whole run: it needs {STATE}")
        if not (args.evaluate or args.resume) and held and not args.overwrite:
            raise ValueError(f"{args.out} holds a run: --resume it or --overwrite it")
        if args.evaluate:
            evaluate_into(args.out, lambda: evaluate(args.out, args.episodes, seed=1),
                          args.overwrite)
            return
        torch.set_num_threads(1)  # one core: the machine has two
        train(args.out, args.total_frames, args.frames_per_level, args.checkpoint_every,
              args.seed, args.resume, compile_step=not args.eager)


if __name__ == "__main__":
    main()
