"""Per-occupancy evaluation of a checkpoint, beside the paper's Table 2.

    python -m trainers.evaluate CHECKPOINT [--episodes 200] [--out DIR] [--seed 1]
                                           [--videos mp4|gif|none]

Runs the deterministic policy (the TanhNormal's mode) for ``--episodes`` episodes at each
occupancy level on lots the training never drew (its own seed; the same goals and starts at
every level, so the levels differ only in their parked cars), and prints and writes
(``evaluation.md``, ``evaluation.csv``) success, collision and timeout rates, mean episode
length, the failure modes (grazing collisions, freezing: see GRAZING_SPEED, FREEZE_DISTANCE;
braked: episodes in which the emergency brake, when on, stopped a step; docked: episodes
the docking layer, when on, drove to their end),
and the median and 90th percentile of the final position and heading errors; with
``--videos`` (mp4 by default) also one rollout video per level.
"""

from __future__ import annotations

import argparse
import csv
import math
from dataclasses import dataclass
from pathlib import Path

import torch
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException
from torch.utils._pytree import tree_map_only
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp
from torchrl.modules import ProbabilisticActor
from tqdm import tqdm

from torchpark import ParkingEnv
from torchpark.curriculum import PAPER_LEVELS
from torchpark.features import goal_in_vehicle_frame
from torchpark.recording import record_video
from trainers.checkpoint import load_checkpoint
from trainers.config import TrainConfig, check_device
from trainers.models import NORMALISED, make_ppo_models
from trainers.ppo import parking_config, policy_input

# Table 2 of the paper: success rate per curriculum phase (occupancy level).
PAPER_SUCCESS = dict(zip(PAPER_LEVELS, (0.20, 0.52, 0.65, 0.64, 0.59, 0.62), strict=True))
COLUMNS = ("occupancy", "episodes", "success", "collision", "timeout", "grazing", "freezing",
           "braked", "docked", "mean_length", "pos_err_median_m", "pos_err_p90_m",
           "heading_err_median_deg", "heading_err_p90_deg", "paper_success")


def load(path: str) -> tuple[TrainConfig, dict]:
    """The checkpoint's training config and contents (tensors on the CPU); ValueError naming
    the path when it is not a torchpark checkpoint."""
    checkpoint = load_checkpoint(path)
    try:
        merged = OmegaConf.merge(OmegaConf.structured(TrainConfig), checkpoint["config"])
        return OmegaConf.to_object(merged), checkpoint
    except OmegaConfBaseException as err:
        raise ValueError(f"checkpoint {str(path)!r} has an invalid config: "
                         f"{str(err).splitlines()[0]}") from None


def make_eval_env(cfg: TrainConfig, checkpoint: dict, occupancy: float, num_envs: int,
                  seed: int) -> TransformedEnv:
    """``num_envs`` lots at ``occupancy`` with the paper's success test, feeding the policy
    the checkpoint's (frozen) normalisation."""
    base = ParkingEnv(num_envs, device=cfg.env.device, seed=seed,
                      config=parking_config(cfg, training=False))
    base.occupancy = occupancy
    inputs = policy_input(cfg)
    env = TransformedEnv(base, Compose(*inputs))
    norm = inputs[-1]
    norm.load_state_dict(checkpoint["obs_norm"])
    norm.freeze()
    return env


# Failure modes: a collision at |v| <= GRAZING_SPEED is "grazing" (the car crept into an
# obstacle); a timeout whose rear axle moved less than FREEZE_DISTANCE over its last
# FREEZE_STEPS steps is "freezing" (the car stopped short of the goal).
GRAZING_SPEED = 1.0  # m/s
FREEZE_DISTANCE = 1.0  # m
FREEZE_STEPS = 100


@dataclass
class Episodes:
    """The first episode of each of N lots. Bool/float tensors (N,) unless stated.

    poses: (T + 1, N, 3) rear-axle poses after each env step from the reset on (rows repeat
    their last pose after their end); final: (N, 7) the last observation's [dx, dy, cos psi,
    sin psi, v, cos alpha, sin alpha]; length: env steps taken (an index into ``poses``);
    steps: steps of dt taken (``repeat`` per env step when the env holds its actions);
    braked: the emergency brake stopped or steered (``steer_clear``) at least one of the
    episode's steps of dt (each one a collision in the paper's env, which has no brake; with
    the docking layer, the law's count too); docked: the docking layer (when on) had taken
    over by the episode's end.
    """

    success: torch.Tensor
    collision: torch.Tensor
    timeout: torch.Tensor
    length: torch.Tensor
    final: torch.Tensor
    poses: torch.Tensor
    goal_slot: torch.Tensor
    steps: torch.Tensor
    braked: torch.Tensor
    docked: torch.Tensor
    repeat: int = 1

    @property
    def position_error(self) -> torch.Tensor:
        """Distance from the rear axle to its goal at the end, m."""
        return torch.hypot(self.final[:, 0], self.final[:, 1])

    @property
    def heading_error(self) -> torch.Tensor:
        """|wrap(alpha - psi)| at the end, degrees."""
        goal = goal_in_vehicle_frame(self.final)
        return torch.atan2(goal[:, 3], goal[:, 2]).abs() * (180.0 / math.pi)

    @property
    def grazing(self) -> torch.Tensor:
        return self.collision & (self.final[:, 4].abs() <= GRAZING_SPEED)

    @property
    def freezing(self) -> torch.Tensor:
        end = self.length.long()
        rows = torch.arange(end.shape[0])
        before = self.poses[(end - FREEZE_STEPS // self.repeat).clamp(min=0), rows, :2]
        moved = (self.poses[end, rows, :2] - before).norm(dim=-1)
        return self.timeout & (moved < FREEZE_DISTANCE)


def run_episodes(actor, env: TransformedEnv, max_steps: int, desc: str | None = None
                 ) -> Episodes:
    """Run the deterministic policy until every lot's first episode has ended. No row is
    reset: a row that ended steps on, unrecorded, until the last one ends. With ``desc``, a
    progress bar of the episodes ended so far, so labelled."""
    base = env.base_env
    n = base.num_envs
    ended = torch.zeros(n, dtype=torch.bool)
    final = torch.zeros(n, 7)
    outcome = {key: torch.zeros(n, dtype=torch.bool)
               for key in ("success", "collision", "truncated")}
    length = torch.zeros(n)
    steps = torch.zeros(n)
    braked = torch.zeros(n, dtype=torch.bool)
    docked = torch.zeros(n, dtype=torch.bool)
    td = env.reset()
    poses = [base.state.pose.cpu()]
    bar = tqdm(total=n, desc=desc, unit="episode", disable=desc is None, leave=False)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        for step in range(1, max_steps + 1):
            td = env.step(actor(td))
            nxt = td["next"]
            first = nxt["done"][:, 0].cpu() & ~ended
            final[first] = nxt["observation"][:, :7].cpu()[first]
            for key in outcome:
                outcome[key] |= first & nxt[key][:, 0].cpu()
            length[first] = step
            docked[first] = base.state.docking.cpu()[first]
            braked[first] = base.state.brakes.cpu()[first] > 0
            steps[first] = base.state.steps.cpu()[first].float()
            poses.append(torch.where(ended[:, None], poses[-1], base.state.pose.cpu()))
            ended |= first
            bar.update(int(first.sum()))
            if bool(ended.all()):
                break
            td = step_mdp(td)
    bar.close()
    return Episodes(outcome["success"], outcome["collision"], outcome["truncated"], length,
                    final, torch.stack(poses), base.state.goal_slot.cpu(), steps, braked,
                    docked, base.config.action_repeat)


def evaluate_level(actor, checkpoint: dict, cfg: TrainConfig, occupancy: float,
                   episodes: int, seed: int) -> dict[str, float]:
    """One episode in each of ``episodes`` lots at ``occupancy``: the row of the table."""
    env = make_eval_env(cfg, checkpoint, occupancy, episodes, seed)
    run = run_episodes(actor, env, cfg.env.max_steps, desc=f"occupancy {occupancy:.0%}")
    position, heading = run.position_error, run.heading_error
    return {
        "occupancy": occupancy, "episodes": episodes,
        "success": run.success.float().mean().item(),
        "collision": run.collision.float().mean().item(),
        "timeout": run.timeout.float().mean().item(),
        "grazing": run.grazing.float().mean().item(),
        "freezing": run.freezing.float().mean().item(),
        "braked": run.braked.float().mean().item(),
        "docked": run.docked.float().mean().item(),
        "mean_length": run.steps.mean().item(),
        "pos_err_median_m": position.median().item(),
        "pos_err_p90_m": position.quantile(0.9).item(),
        "heading_err_median_deg": heading.median().item(),
        "heading_err_p90_deg": heading.quantile(0.9).item(),
        "paper_success": PAPER_SUCCESS.get(occupancy, float("nan")),
    }


def make_policy(cfg: TrainConfig, checkpoint: dict) -> ProbabilisticActor:
    """The checkpoint's actor (it reads ``NORMALISED``, see :func:`make_eval_env`)."""
    probe = TransformedEnv(ParkingEnv(1, device=cfg.env.device), Compose(*policy_input(cfg)))
    actor, _ = make_ppo_models(probe.observation_spec[NORMALISED].shape[-1], probe.action_spec,
                               cfg.model)
    actor.load_state_dict(checkpoint["actor"])
    return actor.to(cfg.env.device)


def evaluate(path: str, episodes: int = 200, levels=PAPER_LEVELS, seed: int = 1,
             videos: Path | None = None, video_format: str = "mp4",
             device: str | None = None) -> list[dict[str, float]]:
    """The table's rows, one per level; with ``videos``, also one rollout video per level
    (``rollout_occ{percent}.{video_format}``) of the deterministic policy in that directory.
    ``device``: where the envs and the policy run (default: the checkpoint's training
    device)."""
    cfg, checkpoint = load(path)
    if device is not None:
        cfg.env.device = device
    check_device(cfg.env.device, "the evaluation's device (the training's unless --device)")
    checkpoint = tree_map_only(torch.Tensor, lambda t: t.to(cfg.env.device), checkpoint)
    actor = make_policy(cfg, checkpoint)
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
    parser.add_argument("--overwrite", action="store_true",
                        help="replace evaluation files already in --out (refused by default)")
    parser.add_argument("--device", default=None,
                        help="torch device of the envs and the policy (default: the training's)")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    out = Path(args.out) if args.out else Path(args.checkpoint).parent
    outputs = [out / "evaluation.md", out / "evaluation.csv"]
    if args.videos != "none":
        outputs += [out / f"rollout_occ{round(100 * level)}.{args.videos}"
                    for level in PAPER_LEVELS]
    existing = [str(p) for p in outputs if p.exists()]
    if existing and not args.overwrite:
        parser.error(f"{existing[0]} exists ({len(existing)} of the outputs do): pass --out "
                     f"another directory, or --overwrite to replace them")
    try:
        out.mkdir(parents=True, exist_ok=True)
        rows = evaluate(args.checkpoint, args.episodes, seed=args.seed,
                        videos=None if args.videos == "none" else out,
                        video_format=args.videos, device=args.device)
    except (ValueError, OSError) as err:
        parser.exit(2, f"{parser.prog}: error: {str(err).splitlines()[0]}\n")
    table = to_markdown(rows)
    (out / "evaluation.md").write_text(table + "\n")
    with open(out / "evaluation.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    print(table)


if __name__ == "__main__":
    main()
