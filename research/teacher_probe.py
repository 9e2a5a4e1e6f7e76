"""The distiller's teacher driving the evaluator's lots: how often it parks, stalls and needs
its brake, per occupancy level, and in which phase the brake acts (research/experiments.md).
From the repository's root, the committed student's teacher:

    python -m research.teacher_probe --headings 96 --funnel 0.6 0.55 --handover 50 \
        --car-margin 0.2 --levels 0 0.9 --cache /tmp/tables

Without those four options it is the teacher before the look-ahead (that of
research/results/reverse_margin/: the expert of ``results/fast/`` with ``--settle 0.05
--retry 1 --gear-hold 0.75 --target-lateral 0.25 --target-heading 0.12 --reverse-margin
0.5``). The lots are the evaluator's (``--seed 1``, 200 a level), through the committed
student's env. ``--cache`` keeps each planner's tables (a torch file of one tensor) between
runs: the 96-heading tables take about 6 min to build on two cores.
"""

from __future__ import annotations

import argparse
import hashlib
import time
from pathlib import Path

import torch

import trainers.distill as distill
from torchpark.experts import planner as plan
from torchpark.experts.config import PlannerConfig
from torchpark.runner import run_episodes
from torchpark.transforms.actions import gear_inverse, power_map_inverse
from trainers.checkpoint import load_trained
from trainers.evaluate import checkpoint_agent, level_row

STUDENT = "results/policy_alone/checkpoint_best.pt"
TEACHER = "results/fast/checkpoint_final.pt"


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


def teacher_planner(headings: int, funnel: tuple[float, float] | None, car_margin: float
                    ) -> PlannerConfig:
    """The teacher's planner: the committed student's target and gear hold, with ``headings``,
    the law's ``funnel`` (lateral m, heading rad; None: the target's) and ``car_margin`` m
    (the committed student's: 96, (0.6, 0.55), 0.2)."""
    law = {} if funnel is None else dict(law_lateral=funnel[0], law_heading=funnel[1])
    return PlannerConfig(headings=headings, gear_hold=0.75, lateral=0.25, heading=0.12,
                         car_margin=car_margin, **law)


def make_teacher(env, planner: PlannerConfig, reverse_margin: float = 0.5, handover: int = 0
                 ) -> distill.Teacher:
    """The distiller's teacher on ``env``: ``TEACHER``'s aids with the committed law's settle
    and retry, ``planner``, ``reverse_margin`` m and ``handover`` steps."""
    return distill.Teacher(TEACHER, env, settle=0.05, retry=1.0, planner=planner,
                           reverse_margin=reverse_margin, handover=handover)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.9])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--headings", type=int, default=64)
    parser.add_argument("--funnel", type=float, nargs=2, default=None,
                        metavar=("LATERAL", "HEADING"))
    parser.add_argument("--handover", type=int, default=0)
    parser.add_argument("--car-margin", type=float, default=0.0)
    parser.add_argument("--reverse-margin", type=float, default=0.5)
    parser.add_argument("--cache", type=Path, default=None)
    args = parser.parse_args()
    if args.cache is not None:
        plan.cost_to_go = cached(args.cache)
    planner = teacher_planner(args.headings, args.funnel, args.car_margin)
    exponents = torch.tensor(load_trained(STUDENT)[0].agent.action_exponents)
    agent = checkpoint_agent(STUDENT)
    for level in args.levels:
        probe_level(agent, level, args, planner, exponents)


def probe_level(agent, level: float, args: argparse.Namespace, planner: PlannerConfig,
                exponents: torch.Tensor) -> None:
    """One level's episodes, the teacher driving; prints its row."""
    env = agent.make_env(level, args.episodes, args.seed)
    teacher = make_teacher(env, planner, args.reverse_margin, args.handover)
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
