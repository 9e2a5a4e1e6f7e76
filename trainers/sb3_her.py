"""A goal-conditioned baseline: Stable-Baselines3's SAC with hindsight relabelling
(``HerReplayBuffer``) on ``torchpark/ParkingGoal-v0`` (:mod:`torchpark.goal_env`), with the
settings of highway-env's ``parking-v0`` examples (SAC + HER, 4 ``future`` goals per
transition, gamma 0.95, learning rate 1e-3, 3 x 256 MLPs, batch 256), the occupancy raised
through the paper's six levels in equal parts of the run; then the per-level evaluation.

    python -m trainers.sb3_her --out results/her                  # train (1 h on one core)
    python -m trainers.sb3_her --out results/her --evaluate       # the three-threshold table

The env is the paper's (no aid, uniform starts, reward and success test as in Table 1, one
lot stepped at a time: SAC updates after every step). ``state.pt`` (``--checkpoint-every``
frames, and at the end) holds the policy's weights and the frame count, tensors only, each
write whole or not at all; the evaluation reads it. A stopped run starts again: the replay
buffer, which an exact resume would need, is not saved (SB3 pickles it, and nothing this
project loads from disk runs code).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium
import numpy as np
import torch
from stable_baselines3 import SAC, HerReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from torchrl.envs import TransformedEnv

from torchpark.curriculum import PAPER_LEVELS, level_at
from torchpark.files import directory_arg, locked, save_torch
from torchpark.goal_env import GOAL_ENV_ID, goal_observation
from trainers.checkpoint import load_checkpoint, load_weights
from trainers.evaluate import evaluate_agent, evaluate_into, run_command, sb3_agent
from trainers.sb3_paper import parking_env

STATE = "state.pt"
STATE_KEYS = frozenset({"frames", "policy", "wall_clock_s"})


def new_model(seed: int, out: Path | None = None, compile_step: bool = True) -> SAC:
    """SAC + HER with highway-env's parking hyperparameters (TensorBoard logs in ``out``)."""
    env = gymnasium.make(GOAL_ENV_ID, seed=seed, compile_step=compile_step)
    return SAC("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer,
               replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future",
                                     "copy_info_dict": True},
               learning_rate=1e-3, gamma=0.95, batch_size=256, buffer_size=1_000_000,
               learning_starts=1_000, policy_kwargs={"net_arch": [256, 256, 256]},
               seed=seed, device="cpu", tensorboard_log=None if out is None else str(out))


class Schedule(BaseCallback):
    """The occupancy (level k of the paper's six from k x ``frames_per_level`` frames on, for
    lots drawn at later resets), the episodes' success rate and the wall-clock in
    TensorBoard, and ``state.pt`` every ``every`` frames."""

    def __init__(self, out: Path, frames_per_level: int, every: int) -> None:
        super().__init__()
        self.out, self.frames_per_level, self.every = out, frames_per_level, every
        self.started = time.perf_counter()

    def level(self) -> float:
        return PAPER_LEVELS[level_at(self.num_timesteps, self.frames_per_level,
                                     len(PAPER_LEVELS))]

    def _on_step(self) -> bool:
        parking_env(self.model).occupancy = self.level()
        if self.num_timesteps % self.every == 0:
            save(self.model, self.out, time.perf_counter() - self.started)
        if self.num_timesteps % 1_000 == 0:
            self.logger.record("curriculum/occupancy", self.level())
            self.logger.record("time/wall_clock_s", time.perf_counter() - self.started)
        return True


def save(model: SAC, out: Path, wall_clock: float) -> None:
    save_torch({"frames": model.num_timesteps, "policy": model.policy.state_dict(),
                "wall_clock_s": wall_clock}, out / STATE)


def train(out: Path, total: int, every: int, seed: int, compile_step: bool = True) -> SAC:
    """Train the baseline; ``state.pt`` and TensorBoard in ``out`` (locked by the caller)."""
    out.mkdir(parents=True, exist_ok=True)
    model = new_model(seed, out, compile_step)
    schedule = Schedule(out, -(-total // len(PAPER_LEVELS)), every)
    model.learn(total, callback=schedule, tb_log_name="sac_her", progress_bar=True)
    save(model, out, time.perf_counter() - schedule.started)
    return model


def evaluate(out: Path, episodes: int, seed: int) -> list[dict]:
    """The baseline's table: its deterministic policy, ``episodes`` lots per level, the
    paper's env, success at C < 4e-4, 4e-3 and 4e-2."""
    state = load_checkpoint(out / STATE, "cpu", STATE_KEYS)
    model = new_model(0, compile_step=False)
    load_weights(model.policy, state["policy"], out / STATE, "policy")
    policy = (f"SAC + HER (Stable-Baselines3, highway-env's parking settings), "
              f"{int(state['frames']):,} frames, {float(state['wall_clock_s']) / 60:.0f} min")

    def observe(env: TransformedEnv, td) -> dict[str, np.ndarray]:
        obs = goal_observation(td["observation"], env.base_env.state)
        return {key: value.numpy() for key, value in obs.items()}

    return evaluate_agent(sb3_agent(model.predict, observe, policy), episodes, seed=seed)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m trainers.sb3_her",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=directory_arg, default=Path("results/her"))
    parser.add_argument("--total-frames", type=int, default=100_000)
    parser.add_argument("--checkpoint-every", type=int, default=10_000, help="frames")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--overwrite", action="store_true",
                        help="start afresh in an --out that holds a run, or replace an "
                             "evaluation there")
    parser.add_argument("--evaluate", action="store_true",
                        help="write evaluation.md/.csv for the policy in --out")
    parser.add_argument("--episodes", type=int, default=200, help="per level (--evaluate)")
    args = parser.parse_args(argv)
    run_command(parser, args, ("total_frames", "checkpoint_every", "episodes"), run)


def run(args: argparse.Namespace) -> None:
    """What ``main`` was asked, with the output directory locked."""
    with locked(args.out, "--out"):
        if args.evaluate:
            if not (args.out / STATE).exists():
                raise ValueError(f"{args.out} holds no run: it needs {STATE}")
            evaluate_into(args.out, lambda: evaluate(args.out, args.episodes, seed=1),
                          args.overwrite)
            return
        if (args.out / STATE).exists() and not args.overwrite:
            raise ValueError(f"{args.out} holds a run: --overwrite to start it afresh")
        torch.set_num_threads(1)  # one core: the machine has two
        train(args.out, args.total_frames, args.checkpoint_every, args.seed)


if __name__ == "__main__":
    main()
