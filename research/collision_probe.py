"""Where a checkpoint's agent collides on the evaluator's lots: for each collision, how far
its rear axle is from its goal (m), its speed at the end (m/s, negative in reverse) and the
step of dt it ends on; for the collisions in an episode's first ``--early`` steps, the
distance the agent and the committed teacher (``trainers.evaluate --expert teacher``, the
same lot from the same start) travel along the car's heading in their first 3 steps, and
whether the teacher collides or parks there (research/experiments.md). From the
repository's root:

    python -m research.collision_probe results/policy_alone/checkpoint_best.pt \\
        --levels 0.4 0.6 0.8 0.9 --seeds 1 777

The teacher's planner tables take a few minutes to build on two cores.
"""

from __future__ import annotations

import argparse

import torch

from torchpark.runner import Episodes
from trainers.evaluate import checkpoint_agent, load_expert, run_level


def along_heading(run: Episodes, rows: torch.Tensor, steps: int = 3) -> torch.Tensor:
    """The rear axle's travel (m) along the start heading over the first ``steps``, per row
    of ``rows``: positive forwards."""
    start = run.poses[0, rows]
    moved = run.poses[steps, rows, :2] - start[:, :2]
    return moved[:, 0] * torch.cos(start[:, 2]) + moved[:, 1] * torch.sin(start[:, 2])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--levels", type=float, nargs="+", default=[0.4, 0.6, 0.8, 0.9])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 777])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--early", type=int, default=50)
    args = parser.parse_args(argv)
    agent, teacher = checkpoint_agent(args.checkpoint), load_expert("teacher")
    for seed in args.seeds:
        for level in args.levels:
            run = run_level(agent, level, args.episodes, seed)
            hit = run.collision
            cases = " ".join(f"[{d:.2f} m, {v:+.2f} m/s, step {int(t)}]" for d, v, t in zip(
                run.position_error[hit].tolist(), run.final[hit, 4].tolist(),
                run.length[hit].tolist(), strict=True))
            print(f"seed {seed}, {level:.0%}: {int(hit.sum())} collisions: {cases}")
            early = torch.nonzero(hit & (run.length <= args.early))[:, 0]
            if early.numel():
                expert = run_level(teacher, level, args.episodes, seed)
                print(f"  in the first {args.early} steps: episodes {early.tolist()}; travel "
                      f"along the heading in 3 steps, the agent's "
                      f"{[round(x, 2) for x in along_heading(run, early).tolist()]}, the "
                      f"teacher's {[round(x, 2) for x in along_heading(expert, early).tolist()]}"
                      f"; the teacher collides {expert.collision[early].tolist()}, parks "
                      f"{expert.success[early].tolist()}", flush=True)


if __name__ == "__main__":
    main()
