"""Per-occupancy evaluation of a checkpoint, beside the paper's Table 2.

    python -m trainers.evaluate CHECKPOINT [--episodes 200] [--out DIR] [--seed 1]
                                           [--videos mp4|gif|none] [--aids NAME=VALUE ...]
                                           [--sample TORCH_SEED] [--collision-substeps K]
    python -m trainers.evaluate --expert planner|teacher --out DIR [...]

Runs the deterministic policy (the TanhNormal's mode; with ``--sample S``, actions drawn from
the policy's distribution, torch seeded with S at each level) for ``--episodes``
episodes at each occupancy level on lots the training never drew (its own seed; the same
goals and starts at every level, so the levels differ only in their parked cars), and prints
and writes
(``evaluation.md``, ``evaluation.csv``) what the agent is made of (COMPOSITION), success at
the paper's C < 4e-4 and at 4e-3 and 4e-2 (the same episodes), collision and timeout rates,
mean episode length, the failure modes (grazing collisions, freezing: see
torchpark.runner; braked: episodes in which the emergency brake, when on, stopped a step;
docked: episodes the docking law, when on, drove to their end), and the median and 90th
percentile of the final position and heading errors; with ``--videos`` (mp4 by default) also
one rollout video per level. ``--aids`` puts the checkpoint's policy under other agent-side
aids than it was trained with (EVALUATION_AIDS: the brake and the docking law, which act
around the network and leave its input and output as trained), e.g. a policy alone as the
approach of a hybrid: ``--aids brake.steer_clear=5 docking={}``. The collision test (named
in the table) is the agent's task's, the paper's end pose unless trained otherwise;
``--collision-substeps K`` tests K poses along each step's motion instead
(``ParkingConfig.collision_substeps``).
``--expert planner`` evaluates the hand-written agent (:mod:`torchpark.experts`: approach
planner, docking law, brake) on the same lots, as a reference any learned agent can be set
beside; ``--expert teacher`` the distiller's teacher (the same parts composed outside a
paper's env, with the labels the committed policy alone was distilled from).
"""

from __future__ import annotations

import argparse
import dataclasses
import textwrap
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import torch
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchpark import AidsConfig, ParkingConfig, ParkingEnv
from torchpark.config import MAX_COLLISION_SUBSTEPS, SEED_LIMIT, check_seed, is_integer
from torchpark.curriculum import PAPER_LEVELS
from torchpark.experts import ExpertConfig, PlannerExpert, Teacher, TeacherConfig
from torchpark.files import directory_arg, locked, write_csv, write_text
from torchpark.media.recording import record_video
from torchpark.runner import Episodes, run_episodes
from trainers.agent import load_agent
from trainers.config import TrainConfig, check_agent, check_device, override
from trainers.distill.config import PRESETS as DISTILL_PRESETS

# Table 2 of the paper: success rate per curriculum phase (occupancy level).
PAPER_SUCCESS = dict(zip(PAPER_LEVELS, (0.20, 0.52, 0.65, 0.64, 0.59, 0.62), strict=True))
# What the agent is made of, in its own columns, so that no table is taken for another.
COMPOSITION = ("agent", "brake", "docking_law", "action_repeat", "actions", "policy")
# success: the paper's C < 4e-4; success_4e-3 and success_4e-2 the looser tests, from the
# same episodes (torchpark.runner.SUCCESS_THRESHOLDS).
RESULTS = ("occupancy", "episodes", "success", "success_4e-3", "success_4e-2", "collision",
           "timeout", "grazing", "freezing", "braked", "docked", "mean_length",
           "pos_err_median_m", "pos_err_p90_m", "heading_err_median_deg", "heading_err_p90_deg",
           "paper_success")
COLUMNS = COMPOSITION + RESULTS
# The agent's aids (torchpark.AidsConfig) --aids may set: those around the network.
# --episodes: lots per level, all stepped at once (a typo must not allocate the machine's
# memory).
MAX_EPISODES = 1_000_000
# The hand-written agents --expert names (torchpark.experts), and their COMPOSITION policy.
EXPERTS = {"planner": "the approach planner (torchpark.experts.PlannerExpert), hand-written",
           "teacher": "the distiller's teacher (torchpark.experts.Teacher, the policy_alone "
                      "preset's), hand-written"}
EVALUATION_AIDS = ("brake", "docking")


def with_aids(cfg: TrainConfig, aids: list[str]) -> TrainConfig:
    """``cfg`` with the agent's aids (``agent.aids``) set by ``aids`` (``NAME=VALUE``, NAME
    one of EVALUATION_AIDS or a field of it, e.g. ``brake.steer_clear=5``, ``docking={}``),
    checked as the trainer checks them; ValueError naming the field."""
    for item in aids:
        name = item.split("=", 1)[0]
        if "=" not in item or name.split(".")[0] not in EVALUATION_AIDS:
            raise ValueError(f"--aids takes NAME=VALUE with NAME one of "
                             f"{', '.join(EVALUATION_AIDS)} or a field of one; got {item!r}")
    cfg = override(cfg, [f"agent.aids.{item}" for item in aids])
    check_agent(cfg)
    return cfg


def composition(aids: AidsConfig | None, policy: str, added: bool = False,
                sampled: int | None = None, expert: bool = False) -> dict[str, str | int]:
    """What the evaluated agent is made of: the COMPOSITION columns, from the aids it drives
    with and a description of its ``policy`` (``added``: the aids were given at evaluation,
    not in training; ``sampled``: the torch seed its actions were drawn with, None for the
    deterministic policy; ``expert``: a hand-written agent, no learned part)."""
    brake, law = (aids.brake, aids.docking) if aids is not None else (None, None)
    brake_text = "off" if brake is None else (
        f"steers clear ({brake.steer_clear} angles)" if brake.steer_clear else "stops") + (
        f", keeps {brake.margin:g} m" if brake is not None and brake.margin else "")
    law_text = (f"0-{law.reach:g} m behind the goal, +-{law.lateral:g} m, "
                f"+-{law.heading:.3g} rad" if law is not None else "off")
    parts = [name for name, on in (("emergency brake", brake is not None),
                                   ("docking law", law is not None)) if on]
    if expert:
        agent = "hand-written: approach planner + " + " + ".join(parts)
    elif parts:
        agent = "hybrid: policy + " + " + ".join(parts) + (", added at evaluation" if added
                                                           else "")
    else:
        agent = "policy alone"
    return {
        "agent": agent, "brake": brake_text, "docking_law": law_text,
        "action_repeat": aids.action_repeat if aids is not None else 1,
        "actions": "the mode (deterministic)" if sampled is None
        else f"sampled (torch seed {sampled})",
        "policy": policy,
    }


class Agent(NamedTuple):
    """What the evaluator runs: ``make_env(occupancy, episodes, seed)`` builds ``episodes``
    lots at ``occupancy`` with the agent's aids and input transforms, ``policy(env)`` is the
    policy that drives such an env, ``max_steps`` its episodes' limit, ``made_of`` the
    COMPOSITION columns, ``collision_substeps`` the collision test of its envs
    (``ParkingConfig.collision_substeps``; :func:`collision_test`)."""

    make_env: Callable[[float, int, int], TransformedEnv]
    policy: Callable[[TransformedEnv], Callable]
    max_steps: int
    made_of: dict
    collision_substeps: int = 1


def collision_test(substeps: int) -> str:
    """What the collision test of an env with ``substeps`` poses per step of dt
    (``ParkingConfig.collision_substeps``) is, in words."""
    if substeps == 1:
        return "collision test: the paper's, the car's box at the end of each step of dt"
    depth = ParkingConfig(collision_substeps=substeps).collision_miss_depth
    return (f"collision test: along the motion, {substeps} poses per step of dt (misses no "
            f"contact deeper than {1000 * depth:.0f} mm)")


def run_level(agent: Agent, occupancy: float, episodes: int, seed: int,
              sample: int | None = None) -> Episodes:
    """One episode in each of ``episodes`` lots (drawn from ``seed``) at ``occupancy``. With
    ``sample``, the actions are drawn from the policy's distribution, torch seeded with
    ``sample`` first (a level does not depend on the levels before)."""
    env = agent.make_env(occupancy, episodes, seed)
    return run_episodes(agent.policy(env), env, agent.max_steps,
                        desc=f"occupancy {occupancy:.0%}", exploration=exploration(sample))


def evaluate_level(agent: Agent, occupancy: float, episodes: int, seed: int,
                   sample: int | None = None) -> dict[str, float]:
    """The row of the table at ``occupancy`` (:func:`run_level`)."""
    return level_row(run_level(agent, occupancy, episodes, seed, sample), occupancy)


def exploration(sample: int | None) -> ExplorationType:
    """How the policy acts from here: its distribution's mode, or (``sample``, a torch seed)
    draws from it, torch seeded with ``sample`` now."""
    if sample is None:
        return ExplorationType.DETERMINISTIC
    torch.manual_seed(sample)
    return ExplorationType.RANDOM


def level_row(run: Episodes, occupancy: float) -> dict[str, float]:
    """The RESULTS columns of one level from its episodes."""
    position, heading = run.position_error, run.heading_error
    return {
        "occupancy": occupancy, "episodes": run.success.shape[0],
        "success": run.success.float().mean().item(),
        **{name: run.reached[:, run.thresholds.index(threshold)].float().mean().item()
           for name, threshold in (("success_4e-3", 4e-3), ("success_4e-2", 4e-2))},
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


def checkpoint_agent(path: str, device: str | None = None, aids: list[str] | None = None,
                     sample: int | None = None, collision_substeps: int | None = None) -> Agent:
    """The checkpoint's agent (:func:`trainers.agent.load_agent`) as the evaluator runs it
    (see :func:`evaluate` for the arguments); ValueError naming the file or the argument that
    does not fit."""
    if sample is not None and (not is_integer(sample) or not 0 <= sample < SEED_LIMIT):
        raise ValueError(f"sample must be None or a torch seed (an int in [0, 2**32)), got "
                         f"{sample!r}")
    trained = load_agent(path, device)
    if aids:  # around the network: its input and output stay as trained
        trained = dataclasses.replace(trained, config=with_aids(trained.config, aids))
    if collision_substeps is not None:  # the task's collision test, not the agent's
        check_substeps(collision_substeps)
        trained = dataclasses.replace(trained, config=override(
            trained.config, [f"env.task.collision_substeps={collision_substeps}"]))
    task = trained.config.env.task
    return Agent(
        lambda occupancy, episodes, seed: trained.make_env(episodes, occupancy, seed),
        lambda env: trained.policy, task.max_steps,
        composition(trained.aids, trained.trained_by, added=bool(aids), sampled=sample),
        task.collision_substeps)


def check_substeps(value: object) -> int:
    """``value`` as ``ParkingConfig.collision_substeps`` takes it, or ValueError naming
    --collision-substeps and its range."""
    if not is_integer(value) or not 1 <= value <= MAX_COLLISION_SUBSTEPS:
        raise ValueError(f"--collision-substeps must be an int in [1, "
                         f"{MAX_COLLISION_SUBSTEPS}], got {value!r}")
    return int(value)


def paper_lots(aids: AidsConfig | None = None, device: str = "cpu", collision_substeps: int = 1
               ) -> Callable[[float, int, int], TransformedEnv]:
    """``make_env`` of an agent that reads the paper's observation as it is: ``episodes``
    lots of the paper's task (with ``collision_substeps`` poses tested per step of dt) at
    ``occupancy`` from ``seed``, with ``aids`` around it."""
    task = ParkingConfig(collision_substeps=check_substeps(collision_substeps))

    def make_env(occupancy: float, episodes: int, seed: int) -> TransformedEnv:
        base = ParkingEnv(episodes, device=device, seed=seed, config=task, aids=aids)
        base.occupancy = occupancy
        return TransformedEnv(base)
    return make_env


def load_expert(name: str, device: str = "cpu", collision_substeps: int = 1,
                config: ExpertConfig | None = None) -> Agent:
    """A hand-written agent (EXPERTS) on ``device``: the paper's env (with
    ``collision_substeps`` poses tested per step of dt) and its policy reading the env's
    state. ``planner``: :class:`torchpark.experts.PlannerExpert` in an env with its aids;
    ``teacher``: the distiller's :class:`torchpark.experts.Teacher` (the ``policy_alone``
    preset's, :mod:`trainers.distill.config`) in the paper's env, composing its aids itself.
    ``config``: the expert's config instead of its default (an ExpertConfig for the planner,
    a TeacherConfig for the teacher)."""
    if name not in EXPERTS:
        raise ValueError(f"--expert must be one of {list(EXPERTS)}, got {name!r}")
    check_device(device, "--device")
    if name == "teacher":
        teacher = config if config is not None else DISTILL_PRESETS["policy_alone"]().teacher
        if not isinstance(teacher, TeacherConfig):
            raise ValueError(f"the teacher's config must be a TeacherConfig, got "
                             f"{type(teacher).__name__}")
        return Agent(paper_lots(None, device, collision_substeps),
                     lambda env: Teacher(teacher, env), ParkingConfig().max_steps,
                     composition(teacher.aids(), EXPERTS[name], expert=True),
                     collision_substeps)
    expert = config if config is not None else ExpertConfig()
    return Agent(paper_lots(expert.aids(), device, collision_substeps),
                 lambda env: PlannerExpert(env, expert), ParkingConfig().max_steps,
                 composition(expert.aids(), EXPERTS[name], expert=True), collision_substeps)


def evaluate_agent(agent: Agent, episodes: int, levels=PAPER_LEVELS, seed: int = 1,
                   sample: int | None = None) -> list[dict[str, float]]:
    """The table's rows, one per level (:func:`evaluate_level`)."""
    return [{**agent.made_of, **evaluate_level(agent, level, episodes, seed, sample)}
            for level in levels]


def record_rollouts(agent: Agent, out: Path, video_format: str = "mp4",
                    levels=PAPER_LEVELS, seed: int = 1, sample: int | None = None
                    ) -> list[Path]:
    """One rollout video per level, ``out/rollout_occ{percent}.{video_format}``, each written
    whole or not at all."""
    paths = []
    for level in levels:
        env = agent.make_env(level, 1, seed)
        with set_exploration_type(exploration(sample)):
            paths.append(record_video(env, agent.policy(env),
                                      out / f"rollout_occ{round(100 * level)}.{video_format}"))
    return paths


def evaluate(path: str, episodes: int = 200, levels=PAPER_LEVELS, seed: int = 1,
             videos: Path | None = None, video_format: str = "mp4",
             device: str | None = None, aids: list[str] | None = None,
             sample: int | None = None, collision_substeps: int | None = None
             ) -> list[dict[str, float]]:
    """The table's rows, one per level; with ``videos``, also one rollout video per level
    (``rollout_occ{percent}.{video_format}``) of the policy in that directory. ``device``:
    where the envs and the policy run (default: the checkpoint's training device). ``aids``:
    NAME=VALUE settings of the agent's aids (:func:`with_aids`). ``sample``: a torch seed,
    actions drawn from the policy's distribution (seeded so at each level), not its mode.
    ``collision_substeps``: the collision test's poses per step of dt (default: the task's
    own; ``ParkingConfig.collision_substeps``)."""
    agent = checkpoint_agent(path, device, aids, sample, collision_substeps)
    rows = evaluate_agent(agent, episodes, levels, seed, sample)
    if videos is not None:
        record_rollouts(agent, videos, video_format, levels, seed, sample)
    return rows


def to_markdown(rows: list[dict[str, float]], collision_substeps: int = 1) -> str:
    """The rows as a Markdown table, under a line saying what the agent is made of (when the
    rows carry the COMPOSITION columns) and one naming the collision test
    (:func:`collision_test`)."""
    lines = []
    if rows and all(c in rows[0] for c in COMPOSITION):
        lines += ["; ".join(f"{c.replace('_', ' ')}: {rows[0][c]}" for c in COMPOSITION), ""]
    lines += [collision_test(collision_substeps), ""]
    lines += ["| " + " | ".join(RESULTS) + " |", "|" + "---:|" * len(RESULTS)]
    for row in rows:
        lines.append("| " + " | ".join(
            f"{row[c]:.0%}" if c in ("occupancy",) else
            f"{row[c]:d}" if isinstance(row[c], int) else f"{row[c]:.3g}" for c in RESULTS
        ) + " |")
    return "\n".join(lines)


# What the command line prints per level (the full table is in evaluation.md / .csv), and
# the headings it prints them under: 10 columns of 10 characters.
SUMMARY = {"occupancy": "occupancy", "success": "C < 4e-4", "success_4e-3": "4e-3",
           "success_4e-2": "4e-2", "collision": "collision", "timeout": "timeout",
           "freezing": "freezing", "braked": "braked", "docked": "docked",
           "paper_success": "Table 2"}
WIDTH = 100


def summary(rows: list[dict[str, float]], collision_substeps: int = 1) -> str:
    """The rows as a terminal reads them, within WIDTH columns: what the agent is made of
    (wrapped) and the collision test over the SUMMARY columns."""
    lines = []
    if rows and all(c in rows[0] for c in COMPOSITION):
        made_of = "; ".join(f"{c.replace('_', ' ')}: {rows[0][c]}" for c in COMPOSITION)
        lines += [*textwrap.wrap(made_of, WIDTH), ""]
    lines += [*textwrap.wrap(collision_test(collision_substeps), WIDTH), ""]
    width = WIDTH // len(SUMMARY)
    lines.append("".join(f"{name:>{width}}" for name in SUMMARY.values()))
    for row in rows:
        lines.append("".join(f"{row[c]:>{width}.0%}" if c == "occupancy"
                             else f"{row[c]:>{width}.3g}" for c in SUMMARY))
    return "\n".join(lines)


def write_tables(rows: list[dict], out: Path, collision_substeps: int = 1) -> str:
    """Write ``evaluation.md`` (:func:`to_markdown`) and ``evaluation.csv`` (COLUMNS) into
    ``out``, each whole or not at all; returns the Markdown."""
    table = to_markdown(rows, collision_substeps)
    write_csv(out / "evaluation.csv", rows, COLUMNS)
    write_text(out / "evaluation.md", table + "\n")
    return table


def sb3_agent(predict: Callable, observe: Callable, policy: str) -> Agent:
    """A Stable-Baselines3 model's deterministic policy on the paper's lots (no aid):
    ``predict`` is the model's, ``observe(env, td)`` what it reads; its [-1, 1] actions (the
    Gymnasium env's) are scaled to the env's bounds."""
    def drive(env: TransformedEnv) -> Callable:
        high = env.action_spec.space.high[0]

        def act(td):
            action, _ = predict(observe(env, td), deterministic=True)
            return td.set("action", torch.as_tensor(action, dtype=torch.float32) * high)
        return act

    return Agent(paper_lots(), drive, ParkingConfig().max_steps, composition(None, policy))


def evaluate_into(out: Path, rows: Callable[[], list[dict]], overwrite: bool) -> None:
    """Print and write (``evaluation.md``, ``evaluation.csv``) the table ``rows()`` makes,
    refused before any work when ``out`` holds one and ``overwrite`` is not set."""
    if any((out / name).exists() for name in ("evaluation.md", "evaluation.csv")) \
            and not overwrite:
        raise ValueError(f"{out} holds an evaluation: --overwrite to replace it")
    table = rows()
    print(summary(table), flush=True)  # the table first: whatever the disk says
    write_tables(table, out)


def run_command(parser: argparse.ArgumentParser, args: argparse.Namespace,
                counts: tuple[str, ...], run: Callable[[argparse.Namespace], None]) -> None:
    """A Stable-Baselines3 recipe's command line: ``counts`` (argument names) must be >= 1,
    ``--episodes`` at most MAX_EPISODES and ``--seed`` a seed; then ``run(args)``, whose
    ValueError or OSError is one line and exit status 2."""
    for name in counts:
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1")
    if args.episodes > MAX_EPISODES:
        parser.error(f"--episodes must be <= {MAX_EPISODES}, got {args.episodes}")
    try:
        check_seed(args.seed, "--seed")
        run(args)
    except (ValueError, OSError) as err:
        parser.exit(2, f"{parser.prog}: error: {str(err).splitlines()[0]}\n")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m trainers.evaluate",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", nargs="?", help="a torchpark checkpoint (or --expert)")
    parser.add_argument("--expert", choices=sorted(EXPERTS), default=None,
                        help="evaluate a hand-written agent (torchpark.experts) instead")
    parser.add_argument("--episodes", type=int, default=200, help="per occupancy level")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", default=None, type=directory_arg,
                        help="directory (default: the checkpoint's)")
    parser.add_argument("--videos", choices=("mp4", "gif", "none"), default="mp4",
                        help="one rollout video per occupancy level, in --out")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace evaluation files already in --out (refused by default)")
    parser.add_argument("--device", default=None,
                        help="torch device of the envs and the policy (default: the training's)")
    parser.add_argument("--sample", type=int, default=None, metavar="TORCH_SEED",
                        help="draw the actions from the policy's distribution (torch seeded "
                             "with TORCH_SEED at each level) instead of taking its mode")
    parser.add_argument("--aids", nargs="+", default=[], metavar="NAME=VALUE",
                        help="put the policy under other aids: " + ", ".join(EVALUATION_AIDS))
    parser.add_argument("--collision-substeps", type=int, default=None, metavar="K",
                        help="test K poses per step of dt along the car's motion for collision "
                             "(default: the agent's task; 1, the paper's end-pose test, for "
                             "--expert)")
    args = parser.parse_args(argv)
    if not 1 <= args.episodes <= MAX_EPISODES:
        parser.error(f"--episodes must be in [1, {MAX_EPISODES}], got {args.episodes}")
    if args.sample is not None and args.sample < 0:
        parser.error(f"--sample must be a torch seed >= 0, got {args.sample}")
    if args.sample is not None and args.sample >= SEED_LIMIT:
        parser.error(f"--sample must be a torch seed < 2**32, got {args.sample}")
    if (args.checkpoint is None) == (args.expert is None):
        parser.error("give a checkpoint or --expert NAME (one of them)")
    if args.expert is not None and (args.aids or args.sample is not None):
        parser.error("--aids and --sample apply to a checkpoint's policy, not to --expert")
    if args.expert is not None and args.out is None:
        parser.error("--expert needs --out DIR (there is no checkpoint's folder to write to)")
    out = args.out if args.out is not None else Path(args.checkpoint).parent
    videos = None if args.videos == "none" else args.videos
    try:
        check_seed(args.seed, "--seed")
        substeps = 1 if args.collision_substeps is None else args.collision_substeps
        agent = load_expert(args.expert, args.device or "cpu", substeps) \
            if args.expert is not None \
            else checkpoint_agent(args.checkpoint, args.device, args.aids, args.sample,
                                  args.collision_substeps)
        with locked(out, "--out"):
            outputs = [out / "evaluation.md", out / "evaluation.csv"]
            if videos is not None:
                outputs += [out / f"rollout_occ{round(100 * level)}.{videos}"
                            for level in PAPER_LEVELS]
            existing = [str(p) for p in outputs if p.exists()]
            if existing and not args.overwrite:
                raise ValueError(f"{existing[0]} exists ({len(existing)} of the outputs do): "
                                 f"pass --out another directory, or --overwrite to replace "
                                 f"them")
            rows = evaluate_agent(agent, args.episodes, seed=args.seed, sample=args.sample)
            print(summary(rows, agent.collision_substeps), flush=True)  # the table first
            write_tables(rows, out, agent.collision_substeps)
            print(f"every column: {out / 'evaluation.md'} (and .csv)")
            if videos is not None:
                record_rollouts(agent, out, videos, seed=args.seed, sample=args.sample)
    except (ValueError, OSError) as err:
        parser.exit(2, f"{parser.prog}: error: {str(err).splitlines()[0]}\n")


if __name__ == "__main__":
    main()
