"""Per-occupancy evaluation of a checkpoint, beside the paper's Table 2.

    python -m trainers.evaluate CHECKPOINT [--episodes 200] [--out DIR] [--seed 1]
                                           [--videos mp4|gif|none]

Runs the deterministic policy (the TanhNormal's mode) for ``--episodes`` episodes at each
occupancy level on lots the training never drew (its own seed; the same goals and starts at
every level, so the levels differ only in their parked cars), and prints and writes
(``evaluation.md``, ``evaluation.csv``) success, collision and timeout rates, mean episode
length, and the median and 90th percentile of the final position and heading errors; with
``--videos`` (mp4 by default) also one rollout video per level.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import torch
from omegaconf import OmegaConf
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchpark import ParkingConfig, ParkingEnv
from torchpark.curriculum import PAPER_LEVELS
from torchpark.recording import record_video
from trainers.config import TrainConfig
from trainers.models import NORMALISED, make_ppo_models
from trainers.ppo import policy_input

# Table 2 of the paper: success rate per curriculum phase (occupancy level).
PAPER_SUCCESS = dict(zip(PAPER_LEVELS, (0.20, 0.52, 0.65, 0.64, 0.59, 0.62), strict=True))
COLUMNS = ("occupancy", "episodes", "success", "collision", "timeout", "mean_length",
           "pos_err_median_m", "pos_err_p90_m", "heading_err_median_deg",
           "heading_err_p90_deg", "paper_success")


def load(path: str) -> tuple[TrainConfig, dict]:
    checkpoint = torch.load(path, weights_only=False)
    merged = OmegaConf.merge(OmegaConf.structured(TrainConfig), checkpoint["config"])
    return OmegaConf.to_object(merged), checkpoint


def make_eval_env(cfg: TrainConfig, checkpoint: dict, occupancy: float, num_envs: int,
                  seed: int) -> TransformedEnv:
    """``num_envs`` lots at ``occupancy`` with the paper's success test, feeding the policy
    the checkpoint's (frozen) normalisation."""
    base = ParkingEnv(num_envs, device=cfg.env.device, seed=seed,
                      config=ParkingConfig(max_steps=cfg.env.max_steps))
    base.occupancy = occupancy
    inputs = policy_input(cfg)
    env = TransformedEnv(base, Compose(*inputs))
    norm = inputs[-1]
    norm.load_state_dict(checkpoint["obs_norm"])
    norm.freeze()
    return env


def evaluate_level(actor, checkpoint: dict, cfg: TrainConfig, occupancy: float,
                   episodes: int, seed: int) -> dict[str, float]:
    """One episode in each of ``episodes`` lots at ``occupancy``: the row of the table."""
    env = make_eval_env(cfg, checkpoint, occupancy, episodes, seed)
    td = env.reset()
    ended = torch.zeros(episodes, dtype=torch.bool)
    final = torch.zeros(episodes, 7)
    outcome = {key: torch.zeros(episodes, dtype=torch.bool)
               for key in ("success", "collision", "truncated")}
    length = torch.zeros(episodes)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        for step in range(1, cfg.env.max_steps + 1):
            out, td = env.step_and_maybe_reset(actor(td))
            nxt = out["next"]
            first = nxt["done"][:, 0].cpu() & ~ended  # only each lot's first episode counts
            final[first] = nxt["observation"][:, :7].cpu()[first]
            for key in outcome:
                outcome[key] |= first & nxt[key][:, 0].cpu()
            length[first] = step
            ended |= first
            if bool(ended.all()):
                break
    dx, dy, cos_psi, sin_psi, _, cos_alpha, sin_alpha = final.T
    heading = torch.remainder(torch.atan2(sin_alpha, cos_alpha) - torch.atan2(sin_psi, cos_psi)
                              + math.pi, 2 * math.pi) - math.pi
    position = torch.hypot(dx, dy)
    heading_deg = heading.abs() * (180.0 / math.pi)
    return {
        "occupancy": occupancy, "episodes": episodes,
        "success": outcome["success"].float().mean().item(),
        "collision": outcome["collision"].float().mean().item(),
        "timeout": outcome["truncated"].float().mean().item(),
        "mean_length": length.mean().item(),
        "pos_err_median_m": position.median().item(),
        "pos_err_p90_m": position.quantile(0.9).item(),
        "heading_err_median_deg": heading_deg.median().item(),
        "heading_err_p90_deg": heading_deg.quantile(0.9).item(),
        "paper_success": PAPER_SUCCESS.get(occupancy, float("nan")),
    }


def evaluate(path: str, episodes: int = 200, levels=PAPER_LEVELS, seed: int = 1,
             videos: Path | None = None, video_format: str = "mp4") -> list[dict[str, float]]:
    """The table's rows, one per level; with ``videos``, also one rollout video per level
    (``rollout_occ{percent}.{video_format}``) of the deterministic policy in that directory."""
    cfg, checkpoint = load(path)
    probe = TransformedEnv(ParkingEnv(1), Compose(*policy_input(cfg)))
    actor, _ = make_ppo_models(probe.observation_spec[NORMALISED].shape[-1], probe.action_spec,
                               cfg.model)
    actor.load_state_dict(checkpoint["actor"])
    rows = []
    for level in levels:
        rows.append(evaluate_level(actor, checkpoint, cfg, level, episodes, seed))
        if videos is not None:
            env = make_eval_env(cfg, checkpoint, level, 1, seed)
            with set_exploration_type(ExplorationType.DETERMINISTIC):
                record_video(env, actor, videos / f"rollout_occ{round(100 * level)}.{video_format}")
    return rows


def to_markdown(rows: list[dict[str, float]]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---:|" * len(COLUMNS)]
    for row in rows:
        lines.append("| " + " | ".join(
            f"{row[c]:.0%}" if c in ("occupancy",) else
            f"{row[c]:d}" if isinstance(row[c], int) else f"{row[c]:.3g}" for c in COLUMNS
        ) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m trainers.evaluate",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--episodes", type=int, default=200, help="per occupancy level")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", default=None, help="directory (default: the checkpoint's)")
    parser.add_argument("--videos", choices=("mp4", "gif", "none"), default="mp4",
                        help="one rollout video per occupancy level, in --out")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    out = Path(args.out) if args.out else Path(args.checkpoint).parent
    out.mkdir(parents=True, exist_ok=True)
    rows = evaluate(args.checkpoint, args.episodes, seed=args.seed,
                    videos=None if args.videos == "none" else out, video_format=args.videos)
    table = to_markdown(rows)
    (out / "evaluation.md").write_text(table + "\n")
    with open(out / "evaluation.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    print(table)


if __name__ == "__main__":
    main()
