"""The committed student driving the evaluator's lots with its teacher labelling every step
(DAgger's view of its own episodes): where it rocks, what the teacher says there, and
whether the teacher's steering can be fitted on lots the student has not seen
(research/experiments.md, "the teacher labelling the student's rocks"). From the
repository's root:

    python -m research.student_probe --levels 0 0.9 --cache /tmp/tables

It prints, per level, (1) over the last 100 steps of each frozen episode, the student's
changes of gear and at how many of them the teacher's label keeps the car's gear, and how
often the student's steering is two bins (half a lock) or more off the label's, and how
often it turns the other way (its bin and the label's on opposite sides of straight); (2)
those two over every state of every episode, by the label's steering (straight, half or
full lock); then (3), after fine-tuning a copy of the student (the distiller's fit, the committed
learning rate, the frozen episodes' states weighted 5 as ``--stall-weight`` does) on the
states of the even lots, the disagreement on the even lots (fitted) and on the odd ones
(unseen). The teacher is the committed student's (``research.teacher_probe``'s options of
its docstring); ``--cache`` keeps its tables between runs (about 7 min to build).
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import torch
from tensordict import TensorDict

from research.teacher_probe import STUDENT, cached, make_teacher
from torchpark.experts import planner as plan
from torchpark.runner import run_episodes
from torchpark.transforms.actions import gear_select, power_map_inverse
from trainers.agent import TrainedAgent, load_agent
from trainers.distill.config import DaggerConfig
from trainers.distill.fit import fit, passes
from trainers.distill.labels import STUDENT_INPUT
from trainers.utils import NORMALISED

WINDOW = 100  # the evaluator's freezing window, steps


def labelled_episodes(trained: TrainedAgent, level: float, episodes: int, seed: int) -> dict:
    """The student's episodes at ``level`` with the teacher's label at each state: per step
    (T, N) the student's input, its five actions u, the label in its units (speed, steer),
    the sign of the car's speed; per episode its length and whether it froze."""
    exponents = torch.tensor(trained.config.agent.action_exponents)
    env = trained.make_env(episodes, level, seed)
    teacher = make_teacher(env)  # the committed student's (the policy_alone preset's)
    high = env.base_env.action_spec.space.high[0]
    policy = trained.policy
    steps: dict[str, list] = {"inputs": [], "student": [], "label": [], "moving": []}

    def actor(td):
        steps["moving"].append(torch.sign(env.base_env.state.speed))
        steps["label"].append(power_map_inverse(teacher.label(), high, exponents))
        steps["inputs"].append(td[STUDENT_INPUT].clone())
        td = policy(td)
        steps["student"].append(td["action"].clone())
        return td

    run = run_episodes(actor, env, trained.config.env.task.max_steps)
    return {**{k: torch.stack(v) for k, v in steps.items()}, "length": run.length.long(),
            "frozen": run.freezing}


def off_bins(body, u: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
    """How many steering bins the student's u (..., 5) is off the label (..., 2), in the
    label's gear (int64 (...,)); negative where it turns the other way (the two bins on
    opposite sides of straight)."""
    steer = torch.where(label[..., 0] >= 0, u[..., 2], u[..., 4])
    centre = body.bins // 2
    ours = body.label_bin(steer.flatten()) - centre
    theirs = body.label_bin(label[..., 1].flatten()) - centre
    off = (ours - theirs).abs()
    return torch.where(ours * theirs < 0, -off, off).view(steer.shape)


def rocks(data: dict, body) -> str:
    """Part (1): the frozen episodes' last WINDOW steps."""
    changes = kept = off = other = count = 0
    for i in data["frozen"].nonzero()[:, 0].tolist():
        end = int(data["length"][i])
        span = slice(max(0, end - WINDOW), end)
        gear = torch.sign(gear_select(data["student"][span, i])[:, 0])
        moving = data["moving"][span, i]
        label_gear = torch.where(data["label"][span, i, 0] >= 0, 1.0, -1.0)
        change = (moving != 0) & (gear != moving)
        changes += int(change.sum())
        kept += int((change & (label_gear == moving)).sum())
        bins = off_bins(body, data["student"][span, i], data["label"][span, i])
        off += int((bins.abs() >= 2).sum())
        other += int((bins < 0).sum())
        count += end - span.start
    frozen = int(data["frozen"].sum())
    return (f"{frozen} frozen: the student changes gear {changes} times in their last "
            f"{WINDOW} steps; the teacher's label keeps the car's gear at {kept} of them; "
            f"steering >= 2 bins off in {off / max(count, 1):.2f} of their steps, the "
            f"other way in {other / max(count, 1):.2f}")


def alive(data: dict) -> torch.Tensor:
    """(T, N) bool: the steps before each episode's end."""
    t = torch.arange(data["label"].shape[0])[:, None]
    return t < data["length"][None, :]


def by_label(off: torch.Tensor, label: torch.Tensor) -> str:
    """The fraction of states >= 2 bins off, by the label's steering class."""
    steer = label[:, 1].abs()
    classes = (("straight", steer < 0.25), ("half lock", (steer >= 0.25) & (steer < 0.75)),
               ("full lock", steer >= 0.75))
    return ", ".join(f"{name} {(off[m].abs() >= 2).float().mean():.3f} (the other way "
                     f"{(off[m] < 0).float().mean():.3f}; n {int(m.sum())})"
                     for name, m in classes)


def steering_head(actor):
    """The student's binned gear head (:class:`trainers.heads.BinnedGearHead`) in its actor."""
    return actor.module[0].module[0]


def fit_probe(trained: TrainedAgent, data: list[dict], epochs: int) -> str:
    """Part (3): a copy of the student fine-tuned on the even lots' states."""
    actor = copy.deepcopy(trained.policy)
    body = steering_head(actor)
    norm = trained.make_env(1, 0.0, 0).transform[-1].to_observation_norm()
    columns = {k: [] for k in ("inputs", "label", "weight", "even", "frozen")}
    for d in data:
        mask = alive(d)
        n = mask.shape[1]
        frozen = d["frozen"][None, :].expand_as(mask)
        columns["inputs"].append(d["inputs"][mask])
        columns["label"].append(d["label"][mask])
        columns["frozen"].append(frozen[mask])
        columns["weight"].append(torch.where(frozen[mask], 5.0, 1.0))
        columns["even"].append((torch.arange(n) % 2 == 0)[None, :].expand_as(mask)[mask])
    x, y, w, even, frozen = (torch.cat(v) for v in columns.values())
    cfg = DaggerConfig(lr=1e-4)
    optim = torch.optim.Adam(actor.parameters(), lr=cfg.lr)
    order, _ = passes(int(even.sum()), int(even.sum()), epochs, 0.0,
                      torch.Generator().manual_seed(0))
    fit(actor, norm, x[even], y[even], w[even], order, cfg, optim)
    with torch.no_grad():
        u = body.action(norm(TensorDict({STUDENT_INPUT: x}, [x.shape[0]]))[NORMALISED])
    off = off_bins(body, u, y)
    return "; ".join(
        f"{name} lots: {(off[m].abs() >= 2).float().mean():.3f} of all states, "
        f"{(off[m & frozen].abs() >= 2).float().mean():.3f} of the frozen episodes' (the "
        f"other way {(off[m & frozen] < 0).float().mean():.3f})"
        for name, m in (("even (fitted)", even), ("odd (unseen)", ~even)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.9])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--cache", type=Path, default=None)
    args = parser.parse_args()
    if args.cache is not None:
        plan.cost_to_go = cached(args.cache)
    trained = load_agent(STUDENT)
    body = steering_head(trained.policy)
    data = []
    for level in args.levels:
        d = labelled_episodes(trained, level, args.episodes, args.seed)
        mask = alive(d)
        off = off_bins(body, d["student"], d["label"])[mask]
        print(f"occupancy {level:.0%}: {rocks(d, body)}", flush=True)
        print(f"  every state, >= 2 bins off, by the label's steering: "
              f"{by_label(off, d['label'][mask])}", flush=True)
        data.append(d)
    print(f"fine-tuned {args.epochs} epochs on the even lots, >= 2 bins off: "
          f"{fit_probe(trained, data, args.epochs)}", flush=True)


if __name__ == "__main__":
    main()
