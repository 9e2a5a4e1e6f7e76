"""The DAgger loop (:func:`distill`): label, aggregate, fit, check, save, per iteration."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import NamedTuple

import torch
from torchrl.envs import Compose, Transform, TransformedEnv

from torchpark.aids.config import NearGoalStarts
from torchpark.env import ParkingEnv
from torchpark.experts import Teacher, TeacherConfig
from torchpark.experts.planner import grid_of
from torchpark.files import save_torch, write_csv
from torchpark.runner import run_episodes
from torchpark.sim.layout import build_layout
from torchpark.transforms.actions import GearActionMap, PowerActionMap
from trainers.checkpoint import load_checkpoint
from trainers.config import TrainConfig, differences
from trainers.distill.aggregate import Aggregate
from trainers.distill.config import DistillConfig
from trainers.distill.fit import fit, passes, plan
from trainers.distill.labels import label_iteration
from trainers.distill.state import STATE, load_state, save_state
from trainers.utils import build_models, make_base_env, policy_input

# What a run writes into its folder (none is replaced without --overwrite).
OUTPUTS = ("checkpoint_final.pt", "checkpoint_best.pt", "dagger.csv", STATE)
# The checks that pick checkpoint_best.pt: the paper's test from uniform starts, empty and
# at 90 % (their sum).
BEST_BY = ("uniform_0_0.0004", "uniform_90_0.0004")


def score(row: dict) -> float:
    """A DAgger iteration's score: the sum of its BEST_BY checks."""
    return sum(row[key] for key in BEST_BY)


def checks(actor, run: TrainConfig, obs_norm: dict, episodes: int, seed: int
           ) -> dict[str, float]:
    """The student on the yardstick (near-goal starts, empty lot) and from uniform starts at
    0 % and 90 %: success at the three thresholds and collisions."""
    row = {}
    for name, near, occupancy in (("yardstick", 1.0, 0.0), ("uniform_0", 0.0, 0.0),
                                  ("uniform_90", 0.0, 0.9)):
        aids = dataclasses.replace(run.agent.aids, near_goal_starts=None if near == 0 else
                                   NearGoalStarts(probability=near))
        cfg = dataclasses.replace(run, agent=dataclasses.replace(run.agent, aids=aids))
        base = make_base_env(cfg, training=True, num_envs=episodes, seed=seed)
        base.occupancy = occupancy
        inputs = policy_input(cfg, base)
        env = TransformedEnv(base, Compose(*inputs))
        inputs[-1].load_state_dict(obs_norm)
        inputs[-1].freeze()
        result = run_episodes(actor, env, cfg.env.task.max_steps)
        for k, threshold in enumerate(result.thresholds):
            row[f"{name}_{threshold:g}"] = result.reached[:, k].float().mean().item()
        row[f"{name}_collision"] = result.collision.float().mean().item()
    return row


class Student(NamedTuple):
    """The student being distilled: its training env (``env``, ``base``), the transforms
    of its input outside the env (``features``, for the final-approach states), its actor,
    the optimiser and the power map's exponents."""

    base: ParkingEnv
    env: TransformedEnv
    features: Transform
    actor: torch.nn.Module
    optim: torch.optim.Optimizer
    exponents: torch.Tensor


def student_of(cfg: DistillConfig) -> Student:
    """A fresh student of ``cfg`` (torch's random state seeded by the caller)."""
    run = cfg.student_run()
    base = make_base_env(run, training=True)
    inputs = policy_input(run, base)
    env = TransformedEnv(base, Compose(*inputs))
    # The student's feature transforms (between the action maps and the normaliser), applied
    # outside the env to the final-approach states.
    features = Compose(*[t.clone() for t in inputs[:-1]
                         if not isinstance(t, (PowerActionMap, GearActionMap))])
    actor, _ = build_models(run)
    exponents = torch.tensor(run.agent.action_exponents, device=base.device)
    optim = torch.optim.Adam(actor.parameters(), lr=cfg.dagger.lr)
    return Student(base, env, features, actor, optim, exponents)


def load_student(student: Student, actor: dict, obs_norm: dict) -> None:
    """Put a saved network and input normaliser (frozen) into ``student``."""
    student.actor.load_state_dict(actor)
    student.env.transform[-1].load_state_dict(obs_norm)
    student.env.transform[-1].freeze()


def init_checkpoint(cfg: DistillConfig) -> dict:
    """``student.init``'s checkpoint, read safely; ValueError naming ``student.init`` where it
    is no checkpoint or its student differs from ``cfg.student`` (the first field that
    does)."""
    try:
        checkpoint = load_checkpoint(cfg.student.init)
    except ValueError as err:
        raise ValueError(f"student.init: {err}") from None
    sections = ("env", "agent", "model")
    ours, defaults = dataclasses.asdict(cfg.student_run()), dataclasses.asdict(TrainConfig())
    differ = differences({k: checkpoint["config"].get(k) for k in sections},
                         {k: ours[k] for k in sections}, {k: defaults[k] for k in sections})
    if differ:
        key, theirs, now = differ[0]
        raise ValueError(f"student.init: {cfg.student.init} has student.{key}={theirs!r}, "
                         f"this run student.{key}={now!r} (a fine-tune keeps the student)")
    return checkpoint


def teacher_of(config: TeacherConfig, env: TransformedEnv) -> Teacher:
    """The teacher on the student's env, its planner's tables built (minutes at the
    default grid), saying so."""
    base = env.base_env
    cells = grid_of(build_layout(base.config.lot, base.config.vehicle, "cpu"),
                    config.planner).cells
    print(f"the teacher's planner: its cost-to-go tables over {cells:,} cells (about 3 min on "
          f"two cores at the default grid; teacher.planner.headings=32 for a coarse one) ...",
          flush=True)
    started = time.perf_counter()
    teacher = Teacher(config, env)
    print(f"the teacher's planner ready in {time.perf_counter() - started:.0f} s", flush=True)
    return teacher


def trained_by(cfg: DistillConfig, iterations: int, frames: int, approach: int) -> str:
    """The checkpoint's account of how the student was made."""
    agent, t, d = cfg.student.agent, cfg.teacher, cfg.dagger
    parts = ["gear head", f"features {'/'.join(agent.features) or 'none'}"]
    if "scan_memory" in agent.features:
        parts.append(f"a memory of {agent.memory_scans} scans")
    if cfg.student.model.steer_bins > 0:
        parts.append("binned steering")
    source = "the approach planner with its docking law and brake"
    if t.docking.settle:
        source += f" (its law creeping to the goal within {t.docking.settle:g} m"
        source += (f", retrying {t.docking.retry:g} m back where the test cannot pass)"
                   if t.docking.retry else ")")
    if t.reverse_margin:
        source += f" (its law's reversing passes ending {t.reverse_margin:g} m short of contact)"
    if t.planner.car_margin:
        source += f" (its planner keeping {t.planner.car_margin:g} m off the parked cars)"
    if t.handover:
        source += (f" (its law taking over beyond the target only where {t.handover} steps of "
                   f"it ahead touch nothing)")
    dagger = (f"fine-tuned from {cfg.student.init}, DAgger from the first" if cfg.student.init
              else "DAgger after the first")
    if d.collision_weight != 1.0:
        dagger += (f"; the states up to {d.collision_horizon} steps before its own "
                   f"collisions weighted {d.collision_weight:g}")
    if d.stall_weight != 1.0:
        dagger += f"; the states it stalls from weighted {d.stall_weight:g}"
        if d.stall_from != 1:
            dagger += f" from iteration {d.stall_from}"
    return (f"distilled ({', '.join(parts)}) from {source}: {iterations} iteration(s) "
            f"({dagger}), {frames:,} labelled frames and {approach:,} final-approach states")


def distill(cfg: DistillConfig, out: Path, resume: bool = False) -> Path:
    """Run DAgger into ``out``; returns the final checkpoint's path. After each iteration the
    run's state goes to ``out/``:data:`~trainers.distill.state.STATE` and the iteration's
    labelled states to its aggregate; ``resume`` continues from them exactly (the same
    checkpoints as a run never stopped, bit for bit), to ``cfg.dagger.iterations``."""
    saved = load_state(out, cfg) if resume else None
    torch.manual_seed(cfg.seed)
    generator = torch.Generator().manual_seed(cfg.seed)
    student = student_of(cfg)
    if saved is None and cfg.student.init:  # a resumed run goes on from its own network
        checkpoint = init_checkpoint(cfg)
        load_student(student, checkpoint["actor"], checkpoint["obs_norm"])
    teacher = teacher_of(cfg.teacher, student.env)
    norm = student.env.transform[-1]
    aggregate = Aggregate(out)
    rows: list[dict] = []
    frames = approach = first = 0
    elapsed = 0.0
    if saved is not None:
        first, frames, approach = (saved[k] for k in ("iterations_done", "frames",
                                                       "approach_states"))
        rows, elapsed = saved["rows"], saved["wall_s"]
        load_student(student, saved["actor"], saved["obs_norm"])
        student.optim.load_state_dict(saved["optim"])
        generator.set_state(saved["generator"])
        torch.set_rng_state(saved["torch_rng"])
        student.base.restore(saved["env"])
        aggregate.load(first, student.base.device)
        print(f"resumed after iteration {first} of {cfg.dagger.iterations} ({frames:,} "
              f"labelled frames)", flush=True)
    started = time.perf_counter() - elapsed
    for iteration in range(first, cfg.dagger.iterations):
        part, new_frames, new_approach = label_iteration(
            student.env, student.features, student.actor, teacher, student.exponents,
            cfg.dagger, iteration, generator, iteration == 0 and not cfg.student.init)
        frames, approach = frames + new_frames, approach + new_approach
        aggregate.add(part)
        x, y, w = aggregate.all()
        epochs, replay = plan(cfg.dagger, iteration)
        first_rows = aggregate.parts[0][0].shape[0]  # its final-approach states last
        order, scale = passes(x.shape[0], part[0].shape[0], epochs, replay, generator,
                              kept=(first_rows - approach, first_rows))
        w = w * scale.to(w.device)  # the drawn earlier states stand for all of them
        loss = fit(student.actor, norm.to_observation_norm(), x, y, w, order, cfg.dagger,
                   student.optim)
        row = {"iteration": iteration, "frames": frames, "approach_states": approach,
               "samples": x.shape[0], "loss": loss,
               **checks(student.actor, cfg.student_run(), norm.state_dict(),
                        cfg.dagger.yardstick, cfg.seed + 1000),
               "wall_s": time.perf_counter() - started}
        rows.append(row)
        save_iteration(out, cfg, student, rows, generator,
                       trained_by(cfg, iteration + 1, frames, approach))
    return out / "checkpoint_final.pt"


def save_iteration(out: Path, cfg: DistillConfig, student: Student, rows: list[dict],
                   generator: torch.Generator, account: str) -> None:
    """After an iteration (the last of ``rows``): its row printed and in ``dagger.csv``, the
    final checkpoint, the best one if it scored best (the later on a tie), then the run's
    state (last: a run killed before it resumes from the iteration before, whose files the
    redone iteration rewrites as they were)."""
    row = rows[-1]
    print(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                   for k, v in row.items()), flush=True)
    write_csv(out / "dagger.csv", rows, list(row))
    norm = student.env.transform[-1]
    checkpoint = {"config": dataclasses.asdict(cfg.student_run()), "frames": row["frames"],
                  "actor": student.actor.state_dict(), "obs_norm": norm.state_dict(),
                  "trained_by": account}
    save_torch(checkpoint, out / "checkpoint_final.pt")
    if score(row) >= max(map(score, rows)):
        save_torch(checkpoint, out / "checkpoint_best.pt")
    save_state(out, cfg, {
        "iterations_done": row["iteration"] + 1, "frames": row["frames"],
        "approach_states": row["approach_states"], "rows": rows, "wall_s": row["wall_s"],
        "actor": student.actor.state_dict(), "optim": student.optim.state_dict(),
        "obs_norm": norm.state_dict(), "generator": generator.get_state(),
        "torch_rng": torch.get_rng_state(), "env": student.base.snapshot()})
