"""The distiller's teacher driving the evaluator's lots: how often it parks, stalls and needs
its brake, per occupancy level, and in which phase the brake acts (research/experiments.md).
From the repository's root, the committed student's teacher:

    python -m research.teacher_probe --levels 0 0.9 --cache /tmp/tables [key=value ...]

The teacher is the ``policy_alone`` preset's (``trainers.distill.config``), changed by
dot-list overrides of its ``teacher`` section; e.g. the teacher before the look-ahead (that
of research/results/reverse_margin/): ``teacher.planner.headings=64
teacher.planner.law_lateral=null teacher.planner.law_heading=null teacher.handover=0
teacher.planner.car_margin=0``. The lots are the evaluator's (``--seed 1``, 200 a level),
through the committed student's env. ``--cache`` keeps each planner's tables (a torch file
of one tensor) between runs: the 96-heading tables take about 6 min to build on two cores.
"""

from __future__ import annotations

import argparse
import hashlib
import time
from pathlib import Path

import torch

from torchpark.experts import Teacher
from torchpark.experts import planner as plan
from torchpark.experts.config import PlannerConfig
from torchpark.runner import run_episodes
from torchpark.transforms.actions import gear_inverse, power_map_inverse
from trainers.checkpoint import load_trained
from trainers.distill.config import load_distill_config
from trainers.evaluate import checkpoint_agent, level_row

STUDENT = "results/policy_alone/checkpoint_best.pt"


def cached(cache: Path):
    """``cost_to_go`` keeping its tables in ``cache``, keyed by what they depend on (the
    planner is otherwise built as ever, :func:`~torchpark.experts.planner.build_planner`)."""
    build = plan.cost_to_go

    def cost_to_go(layout, vehicle, cfg: PlannerConfig) -> torch.Tensor:
        table_cfg = (cfg.cell, cfg.headings, cfg.step, cfg.steers, cfg.reverse_cost,
                     cfg.switch_cost, cfg.clearance, cfg.margin, cfg.band_cost, cfg.slot_cost,
                     cfg.reach_min, cfg.reach, cfg.lateral, cfg.heading)
        key = hashlib.sha256(repr((layout.slots.tolist(), layout.walls.tolist(), vehicle,
                                   table_cfg)).encode()).hexdigest()[:16]
        path = cache / f"tables_{key}.pt"
        if path.exists():
            return torch.load(path, map_location=layout.slots.device, weights_only=True)
        value = build(layout, vehicle, cfg)
        cache.mkdir(parents=True, exist_ok=True)
        torch.save(value, path.with_suffix(".tmp"))
        path.with_suffix(".tmp").replace(path)  # whole or not at all
        return value
    return cost_to_go


def make_teacher(env, overrides: list[str] | None = None) -> Teacher:
    """The committed student's teacher on ``env`` (the ``policy_alone`` preset's), with
    dot-list ``overrides`` of its config (``teacher.handover=0``, ...)."""
    return Teacher(load_distill_config("policy_alone", overrides).teacher, env)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.9])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--cache", type=Path, default=None)
    parser.add_argument("overrides", nargs="*", help="the teacher's config as key=value")
    args = parser.parse_args()
    if args.cache is not None:
        plan.cost_to_go = cached(args.cache)
    exponents = torch.tensor(load_trained(STUDENT)[0].agent.action_exponents)
    agent = checkpoint_agent(STUDENT)
    for level in args.levels:
        probe_level(agent, level, args, exponents)


def probe_level(agent, level: float, args: argparse.Namespace, exponents: torch.Tensor
                ) -> None:
    """One level's episodes, the teacher driving; prints its row."""
    env = agent.make_env(level, args.episodes, args.seed)
    teacher = make_teacher(env, args.overrides)
    high = env.base_env.action_spec.space.high[0]
    braked = torch.zeros(args.episodes, dtype=torch.bool)
    in_law = torch.zeros_like(braked)

    def actor(td):
        control = teacher.label()
        braked.logical_or_(teacher.intervened)
        in_law.logical_or_(teacher.intervened & teacher.state.docking_engaged)
        return td.set("action", gear_inverse(power_map_inverse(control, high, exponents)))

    start = time.time()
    row = level_row(run_episodes(actor, env, agent.max_steps), level)
    print(f"occupancy {level:.0%}: success {row['success']:.3f}, collision "
          f"{row['collision']:.3f}, freezing {row['freezing']:.3f}, timeout "
          f"{row['timeout']:.3f}, braked {braked.float().mean():.3f} (in the law's phase "
          f"{in_law.float().mean():.3f}), mean length {row['mean_length']:.0f} steps "
          f"({time.time() - start:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
