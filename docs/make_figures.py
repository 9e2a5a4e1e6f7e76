"""Regenerate the README's pictures with the project's own code.

    python docs/make_figures.py [--checkpoint results/fast/checkpoint_final.pt]

docs/lots.png: one lot at 0, 50 and 90 % occupancy (same goal and start, so only the parked
cars differ). docs/rollout.gif: one episode of the committed policy (deterministic) at 40 %
occupancy, drawn every step. docs/docking.png: the docking law alone (torchpark.docking)
from 24 starts 0-6 m behind their goals, within 0.1 m and 0.1 rad, empty lot: lateral
offset, heading error and the cost C against time, with the success threshold.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import torch
from PIL import Image
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchpark import DockingConfig, LotConfig, ParkingConfig, ParkingEnv
from torchpark.docking import goal_frame_error
from torchpark.recording import record_video
from torchpark.rendering import frame_grid
from torchpark.reward import parking_cost
from trainers.evaluate import load, make_eval_env, make_policy

DOCS = Path(__file__).resolve().parent


def lots_picture(path: Path) -> None:
    frames = []
    for occupancy in (0.0, 0.5, 0.9):
        env = ParkingEnv(1, seed=7)
        env.occupancy = occupancy
        env.reset()
        frames.append(env.render(0))
    Image.fromarray(frame_grid(frames, columns=3)).save(path)


def rollout_animation(checkpoint: str, path: Path, occupancy: float = 0.4) -> None:
    cfg, saved = load(checkpoint)
    actor = make_policy(cfg, saved)
    env = make_eval_env(cfg, saved, occupancy, num_envs=1, seed=1)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        record_video(env, actor, path, max_steps=300, fps=20)


def docking_picture(path: Path, episodes: int = 24, steps: int = 250) -> None:
    config = ParkingConfig(
        lot=LotConfig(near_goal_starts=1.0, near_goal_reach=6.0, near_goal_lateral=0.1,
                      near_goal_heading=0.1),
        docking=DockingConfig(reach=6.0, lateral=0.1, heading=0.1))
    env = ParkingEnv(episodes, seed=0, config=config)
    td = env.reset()
    live = torch.ones(episodes, dtype=torch.bool)
    rows = []  # per step: |lateral| m, |heading| rad, C, live
    for _ in range(steps):
        td = env.step(td.set("action", torch.zeros(episodes, 2)))["next"]
        state = env.state
        error = goal_frame_error(state.pose, state.goal)
        dx, dy = (state.goal[:, :2] - state.pose[:, :2]).unbind(-1)
        cost = parking_cost(dx, dy, state.pose[:, 2], state.goal[:, 2], state.speed,
                            config.reward)
        rows.append((error.lateral.abs(), error.heading.abs(), cost, live.clone()))
        live &= ~td["done"][:, 0]
    time = [0.1 * (t + 1) for t in range(steps)]
    matplotlib.use("Agg")
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), sharex=True)
    titles = ("|lateral offset| (m)", "|heading error| (rad)", "cost C")
    for k, (ax, title) in enumerate(zip(axes, titles, strict=True)):
        values = torch.stack([r[k] for r in rows]).clamp(min=1e-7)
        alive = torch.stack([r[3] for r in rows])
        for i in range(episodes):  # each episode until it ends
            ax.plot([t for t, a in zip(time, alive[:, i], strict=True) if a],
                    values[alive[:, i], i].numpy(), lw=0.8)
        ax.set(yscale="log", title=title, xlabel="time (s)")
    axes[2].axhline(config.reward.success_threshold, color="k", ls="--", lw=1,
                    label="success: C < 4e-4")
    axes[2].legend(loc="upper right")
    fig.suptitle("The docking law alone, starts 0-6 m behind the goal, ±0.1 m, ±0.1 rad "
                 "(empty lot; each line ends with its episode)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="results/fast/checkpoint_final.pt")
    args = parser.parse_args()
    lots_picture(DOCS / "lots.png")
    rollout_animation(args.checkpoint, DOCS / "rollout.gif")
    docking_picture(DOCS / "docking.png")
    print(DOCS / "lots.png", DOCS / "rollout.gif", DOCS / "docking.png")


if __name__ == "__main__":
    main()
