"""Regenerate the README's pictures with the project's own code.

    python docs/make_figures.py [--checkpoint results/fast/checkpoint_final.pt]

docs/lots.png: one lot at 0, 50 and 90 % occupancy (same goal and start, so only the parked
cars differ). docs/rollout.gif: one episode of the committed policy (deterministic) at 40 %
occupancy, drawn every step.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from PIL import Image
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchpark import ParkingEnv
from torchpark.recording import record_video
from torchpark.rendering import frame_grid
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="results/fast/checkpoint_final.pt")
    args = parser.parse_args()
    lots_picture(DOCS / "lots.png")
    rollout_animation(args.checkpoint, DOCS / "rollout.gif")
    print(DOCS / "lots.png", DOCS / "rollout.gif")


if __name__ == "__main__":
    main()
