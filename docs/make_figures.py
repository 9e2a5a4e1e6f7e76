"""Regenerate the README's pictures with the project's own code.

    python -m docs.make_figures [--checkpoint results/fast/checkpoint_final.pt]

docs/lots.png: one lot at 0, 50 and 90 % occupancy (same goal and start, so only the parked
cars differ). docs/rollout.gif: one episode of the committed policy (deterministic) at 40 %
occupancy, drawn every step. docs/docking.png: the docking law alone (torchpark.aids.docking)
from 24 starts in its default funnel at 50 % occupancy, with the emergency brake: the rear
axle's path in the goal's frame (the multi-point turns), the heading error and the cost C
against time, with the success threshold.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import torch
from PIL import Image
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchpark import (
    AidsConfig,
    BrakeConfig,
    DockingConfig,
    NearGoalStarts,
    ParkingConfig,
    ParkingEnv,
)
from torchpark.aids.docking import error_from_goal
from torchpark.media.recording import record_video
from torchpark.media.rendering import picture_grid
from torchpark.sim.reward import parking_cost
from trainers.agent import load_agent

DOCS = Path(__file__).resolve().parent


def lots_picture(path: Path) -> None:
    pictures = []
    for occupancy in (0.0, 0.5, 0.9):
        env = ParkingEnv(1, seed=7)
        env.occupancy = occupancy
        env.reset()
        pictures.append(env.render(0))
    Image.fromarray(picture_grid(pictures, columns=3)).save(path)


def rollout_animation(checkpoint: str, path: Path, occupancy: float = 0.4) -> None:
    agent = load_agent(checkpoint)
    env = agent.make_env(num_envs=1, occupancy=occupancy, seed=1)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        record_video(env, agent.policy, path, max_steps=300, fps=20)


def docking_picture(path: Path, episodes: int = 24, steps: int = 1000,
                    occupancy: float = 0.5) -> None:
    docking = DockingConfig()
    config = ParkingConfig()
    aids = AidsConfig(
        near_goal_starts=NearGoalStarts(probability=1.0, reach=docking.reach,
                                        lateral=docking.lateral, heading=docking.heading,
                                        candidates=32),
        docking=docking, brake=BrakeConfig(steer_clear=5))
    env = ParkingEnv(episodes, seed=0, config=config, aids=aids)
    env.occupancy = occupancy
    td = env.reset()

    def row(live: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """remaining m, lateral m, |heading| rad, C, live, (episodes,) each."""
        state = env.state
        error = error_from_goal(state.pose, state.goal)
        dx, dy = (state.goal[:, :2] - state.pose[:, :2]).unbind(-1)
        cost = parking_cost(dx, dy, state.pose[:, 2], state.goal[:, 2], state.speed,
                            config.reward)
        return error.remaining, error.lateral, error.heading.abs(), cost, live.clone()

    live = torch.ones(episodes, dtype=torch.bool)
    rows = [row(live)]
    for _ in range(steps):
        td = env.step(td.set("action", torch.zeros(episodes, 2)))["next"]
        rows.append(row(live))
        live &= ~td["done"][:, 0]
    remaining, lateral, heading, cost, alive = (torch.stack(c) for c in zip(*rows, strict=True))
    time = torch.arange(steps + 1) * config.vehicle.dt
    matplotlib.use("Agg")
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for i in range(episodes):  # each episode until it ends
        a = alive[:, i]
        line, = axes[0].plot(lateral[a, i], remaining[a, i], lw=0.8)
        axes[0].plot(lateral[0, i], remaining[0, i], "o", ms=3, color=line.get_color())
        axes[1].plot(time[a], heading[a, i].clamp(min=1e-7), lw=0.8, color=line.get_color())
        axes[2].plot(time[a], cost[a, i].clamp(min=1e-7), lw=0.8, color=line.get_color())
    slot = config.lot
    mouth = slot.slot_length / 2.0 - config.vehicle.centre_offset  # goal axle to slot mouth
    axes[0].plot([-slot.slot_width / 2, -slot.slot_width / 2, slot.slot_width / 2,
                  slot.slot_width / 2], [mouth, mouth - slot.slot_length,
                                         mouth - slot.slot_length, mouth], "k-", lw=1.2)
    axes[0].set(title="rear axle in the goal's frame (o: start)", xlabel="lateral offset (m)",
                ylabel="distance behind the goal (m)", aspect="equal")
    axes[1].set(yscale="log", title="|heading error| (rad)", xlabel="time (s)")
    axes[2].set(yscale="log", title="cost C", xlabel="time (s)")
    axes[2].axhline(config.reward.success_threshold, color="k", ls="--", lw=1,
                    label="success: C < 4e-4")
    axes[2].legend(loc="upper right")
    fig.suptitle(f"The docking law alone from its funnel (0-{docking.reach:g} m behind the goal, "
                 f"±{docking.lateral:g} m, any heading), {occupancy:.0%} occupancy, emergency "
                 "brake steering clear; each line ends with its episode")
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
