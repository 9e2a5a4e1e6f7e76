"""The distiller's configuration: one tree of typed sections, torchpark's own configs nested,
not mirrored, and its presets.

- ``teacher``: the expert that labels (:class:`torchpark.experts.TeacherConfig`: the planner,
  the docking law, the brake, its reverse margin and handover);
- ``student``: what is distilled (:class:`StudentConfig`: the env, the agent, the network,
  the sections of a PPO run's :class:`~trainers.config.TrainConfig` of the same names);
- ``dagger``: the schedule and the fit (:class:`DaggerConfig`);
- ``seed``.

Any field is overridden from the command line in OmegaConf dot notation, as PPO's are
(:func:`trainers.config.override`), e.g. ``dagger.iterations=4 student.env.num_envs=64
teacher.planner.headings=32``; an unknown field, a wrong type or a value out of range is an
error naming it before anything runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from torchpark.aids.config import AidsConfig, NearGoalStarts
from torchpark.config import ParkingConfig, check_seed, positive, require
from torchpark.experts import PlannerConfig, TeacherConfig
from trainers.config import PRESETS as PPO_PRESETS
from trainers.config import (
    AgentConfig,
    EnvConfig,
    LoggerConfig,
    ModelConfig,
    TrainConfig,
    check_agent,
    check_model,
    env_configs,
    load_preset,
)


def _student_agent() -> AgentConfig:
    return AgentConfig(aids=AidsConfig(near_goal_starts=NearGoalStarts(probability=0.5)),
                       action_exponents=[3.0, 1.0], gear_head=True, features=["goal"])


@dataclass
class StudentConfig:
    """The student: the env it is trained in (``env``: ``num_envs`` lots per rollout, the
    paper's task), what it reads and how it acts (``agent``) and its network (``model``),
    as a PPO run's sections of those names. A policy alone: no aid acts around it
    (``agent.aids`` only starts half its training episodes near the goal and may observe its
    position), one action per step of dt, a gear and a (speed, steer) pair per gear through
    the power map (``agent.action_exponents`` [3, 1]: 1 mm/s is 0.058 of its output's range,
    not 2e-4), the goal seen from the car; ``model``: ``fast``'s sizes. ``init``: a checkpoint
    of this student (its ``env``, ``agent`` and ``model`` sections these) whose network and
    frozen input normaliser the run starts from, its own states labelled from iteration 0
    on (a fine-tune); "" (default): a fresh student, iteration 0 driven by the teacher."""

    env: EnvConfig = field(default_factory=lambda: EnvConfig(num_envs=128))
    agent: AgentConfig = field(default_factory=_student_agent)
    model: ModelConfig = field(default_factory=lambda: PPO_PRESETS["fast"]().model)
    init: str = ""


@dataclass
class DaggerConfig:
    """DAgger's schedule and the fit. Each of ``iterations`` runs ``steps`` steps of dt at
    each occupancy level (the teacher drives the first, the student the later ones), every
    other row with Gaussian noise of std ``noise`` (in [-1, 1] units) on its action, and
    labels every state; the first also labels ``approach`` final-approach states per level
    (0: none), drawn up to ``approach_reach`` m behind the goal and weighted
    ``approach_weight`` times a rollout state. ``collision_weight``: the weight of the
    rollout states from which the driver collides within ``collision_horizon`` steps (1: as
    any other); ``stall_weight``: of those from which the student stalls
    (:func:`trainers.distill.labels.steps_in_stall`; the weights multiply where both hold)
    in the iterations from ``stall_from`` on (counted from 0 as in ``dagger.csv``). The fit:
    ``epochs`` / ``dagger_epochs`` passes over all the data after the first / each later
    iteration, minibatches of ``batch_size``, Adam at ``lr`` (falling to 0 along a cosine
    over each fit with ``lr_decay``); ``replay``: 0, each pass over the whole aggregate (its
    work grows with the iterations), or r > 0, over the iteration's new states, the
    final-approach states and a fresh uniform draw of r times the new ones among the other
    earlier states, weighted to stand for all of them
    (:func:`trainers.distill.fit.passes`: a pass's work bounded, the run's linear in the
    iterations). ``final_epochs`` > 0: the last iteration's fit is that many passes over the
    whole aggregate instead (a closing refit of the replayed run; 0: as any later
    iteration's). ``yardstick``: episodes per check after each iteration."""

    iterations: int = 2
    steps: int = 400
    noise: float = 0.05
    approach: int = 32768
    approach_reach: float = 2.0
    approach_weight: float = 1.0
    collision_weight: float = 1.0
    collision_horizon: int = 10
    stall_weight: float = 1.0
    stall_from: int = 1
    epochs: int = 32
    dagger_epochs: int = 16
    batch_size: int = 1024
    lr: float = 1e-3
    lr_decay: bool = False
    replay: float = 0.0
    final_epochs: int = 0
    yardstick: int = 200


def _teacher() -> TeacherConfig:
    return TeacherConfig(planner=PlannerConfig())


@dataclass
class DistillConfig:
    teacher: TeacherConfig = field(default_factory=_teacher)
    student: StudentConfig = field(default_factory=StudentConfig)
    dagger: DaggerConfig = field(default_factory=DaggerConfig)
    seed: int = 0

    def student_run(self) -> TrainConfig:
        """The student as a run's TrainConfig, which its checkpoints hold (the evaluator
        and :func:`trainers.agent.load_agent` build its env and policy from it)."""
        return TrainConfig(env=self.student.env, agent=self.student.agent,
                           model=self.student.model,
                           logger=LoggerConfig(exp_name="distilled"), seed=self.seed)


def check(cfg: DistillConfig) -> None:
    """Every range the types and the sections' own dataclasses do not already fix, by dot
    name; the student's agent and model by the checks PPO's config runs."""
    d = cfg.dagger
    for name, high in (("iterations", 1000), ("steps", 100_000), ("epochs", 1000),
                       ("dagger_epochs", 1000), ("batch_size", 1 << 20),
                       ("yardstick", 65536), ("collision_horizon", 1000),
                       ("stall_from", 1000)):
        value = getattr(d, name)
        require(1 <= value <= high, f"dagger.{name}", f"an int in [1, {high}]", value)
    require(0 <= d.final_epochs <= 1000, "dagger.final_epochs", "an int in [0, 1000] (0: the "
            "last fit as the others)", d.final_epochs)
    require(0 <= d.approach <= 1 << 20, "dagger.approach", "an int in [0, 1048576]",
            d.approach)
    for name in ("lr", "approach_reach", "approach_weight", "collision_weight",
                 "stall_weight"):
        positive(f"dagger.{name}", getattr(d, name))
    require(0.0 <= d.noise <= 1.0, "dagger.noise", "in [0, 1]", d.noise)
    require(0.0 <= d.replay <= 1000.0, "dagger.replay", "in [0, 1000] (0: the whole "
            "aggregate each pass)", d.replay)
    check_seed(cfg.seed, "seed")
    run = cfg.student_run()
    n = run.env.num_envs
    require(1 <= n <= 65536, "student.env.num_envs", "an int in [1, 65536]", n)
    require(run.env.device == "cpu", "student.env.device", "cpu (the teacher's planner "
            "runs there)", run.env.device)
    check_model(run.model, "student.model")
    check_agent(run, "student.")
    agent, aids = run.agent, run.agent.aids
    require(agent.gear_head, "student.agent.gear_head", "true (the student is fitted to "
            "the label's gear)", agent.gear_head)
    require(aids.action_repeat == 1 and aids.brake is None and aids.docking is None,
            "student.agent.aids", "no action_repeat, brake or docking (a policy alone: one "
            "action per step of dt, as the teacher labels)", aids)


def _policy_alone() -> DistillConfig:
    """The committed policy alone (``results/policy_alone/``): 22 iterations of 128 envs x
    400 steps a level, a 3 x 512 student with binned steering reading the goal, the rays'
    clearance, the gear and its travel, a memory of 3 scans, the slots' gaps and its
    position; its teacher the 96-heading planner to a tight target with a gear hold and a
    car margin, handing over to ``fast``'s docking law (creeping back, retrying, its
    reversing passes ending 0.5 m short) in a wider funnel where 50 steps of the law ahead
    touch nothing, under ``fast``'s brake. What each setting did: research/experiments.md."""
    fast = PPO_PRESETS["fast"]()
    _, aids = env_configs(fast, training=False)  # the teacher's law and brake: fast's
    assert aids is not None and aids.docking is not None
    teacher = TeacherConfig(
        planner=PlannerConfig(headings=96, lateral=0.25, heading=0.12, law_lateral=0.6,
                              law_heading=0.55, gear_hold=0.75, car_margin=0.2),
        docking=replace(aids.docking, settle=0.05, retry=1.0), brake=aids.brake,
        reverse_margin=0.5, handover=50)
    agent = _student_agent()
    agent = replace(agent, aids=replace(agent.aids, observe_position=True),
                    features=["goal", "clearance", "gear", "scan_memory", "slots", "position"],
                    memory_scans=3)
    student = StudentConfig(agent=agent, model=replace(fast.model, hidden=[512, 512, 512],
                                                       steer_bins=9))
    dagger = DaggerConfig(iterations=22, dagger_epochs=8, approach_weight=10.0,
                          collision_weight=10.0, stall_weight=5.0, stall_from=10,
                          lr_decay=True)
    return DistillConfig(teacher=teacher, student=student, dagger=dagger, seed=1)


# A coarse planner grid whose tables build in seconds (the default's take minutes).
COARSE_PLANNER = PlannerConfig(cell=1.0, headings=32, step=1.5)


def _smoke() -> DistillConfig:
    """Two iterations of 8 envs x 20 steps, in seconds: for tests and CI. The teacher on a
    coarse planner grid (:data:`COARSE_PLANNER`) with ``fast``'s law and brake, a 64 x 64
    student of 50-step episodes."""
    _, aids = env_configs(PPO_PRESETS["fast"](), training=False)
    assert aids is not None
    teacher = TeacherConfig(planner=COARSE_PLANNER, docking=aids.docking, brake=aids.brake)
    student = StudentConfig(env=EnvConfig(num_envs=8, task=ParkingConfig(max_steps=50)),
                            model=ModelConfig())
    dagger = DaggerConfig(iterations=2, steps=20, epochs=1, dagger_epochs=1, approach=16,
                          yardstick=4)
    return DistillConfig(teacher=teacher, student=student, dagger=dagger)


PRESETS = {"policy_alone": _policy_alone, "smoke": _smoke}


def load_distill_config(preset: str, overrides: list[str] | None = None) -> DistillConfig:
    """The preset's config with dot-notation overrides applied and checked."""
    return load_preset(PRESETS, preset, overrides, check)
