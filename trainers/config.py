"""Training configuration: typed dataclasses with torchrl's recipe names, and the presets.

Any field is overridden from the command line in OmegaConf dot notation, e.g.
``collector.total_frames=100000 env.num_envs=64``; an unknown field or a wrong type is an
error before training starts.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import typing
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from torchpark.aids.config import AidsConfig, BrakeConfig, DockingConfig, NearGoalStarts
from torchpark.aids.step import BRAKED, POSITION
from torchpark.checks import check_device
from torchpark.config import ParkingConfig, RewardConfig, check_seed, is_integer, require
from torchpark.curriculum import PAPER_LEVELS
from trainers.features import FEATURES


@dataclass
class EnvConfig:
    """The simulator: ``num_envs`` lots on ``device`` of the training task ``task``
    (torchpark.ParkingConfig, the paper's by default). Evaluation runs the same task with
    the paper's reward and success test (:func:`env_configs`)."""

    num_envs: int = 1
    device: str = "cpu"
    compile_step: bool = False
    # ParkingEnv(reset_in_step=...): the ended rows reset inside the step's function, with no
    # read back per step (torchpark.sim.ring). None: on CUDA only (on the CPU the host path
    # is as fast).
    reset_in_step: bool | None = None
    # E.g. env.task.max_steps=50; env.task.reward.collision_penalty=-1000 (far from the goal
    # the paper's per-step reward 1 - cbrt(C) is below 0, and a -200 crash costs less than a
    # long failed episode); env.task.reward.success_threshold (training's test only).
    task: ParkingConfig = field(default_factory=ParkingConfig)


@dataclass
class AgentConfig:
    """What the agent is made of besides its network: the aids around it (torchpark's own
    AidsConfig: held actions, the emergency brake, the docking law, near-goal starts, its
    position observed) and the transforms between the env and the network. All off: the
    paper's agent. The same in training and evaluation, but for what only trains: near-goal
    starts and the brake's penalty (evaluation keeps the paper's starts and reward)."""

    # E.g. agent.aids.action_repeat=5, agent.aids.brake.steer_clear=5 (a brake is on once
    # any of its fields is set, or with agent.aids.brake={}), agent.aids.docking={},
    # agent.aids.near_goal_starts.probability=0.5, agent.aids.brake=null (off).
    # Frames are steps of dt: a batch of N envs x T actions is N x T x action_repeat frames.
    aids: AidsConfig = field(default_factory=AidsConfig)
    # None: the policy commands (v, delta) directly (the paper). A list: it acts in [-1, 1]
    # and the env receives (max_speed, max_steer) * sign(u) |u| ** exponents
    # (torchpark.PowerActionMap), e.g. [3, 1] for fine speed control near standstill.
    action_exponents: list[float] | None = None
    # With action_exponents: the policy outputs a gear and a (speed, steer) pair per gear
    # (torchpark.GearActionMap, 5 dims); the gear's sign picks forwards or reverse.
    gear_head: bool = False
    # The policy's extra inputs, appended to the paper's observation in this order, by name
    # (trainers.features.FEATURES): "goal" (the goal seen from the car), "clearance" (the
    # gap along each LIDAR ray past the car's box), "gear" (the gear last moved in and the
    # travel in it, from the observed speed over the episode: what a teacher's gear hold
    # decides by), "scan_memory" (per ray, the nearest gap of this scan and the
    # memory_scans before it, in that ray's sector: the corners one scan's 16 rays pass
    # between), "slots" (per ray, the gap to the nearest slot but the goal's: what a teacher
    # keeping off empty slots steers by, which the LIDAR does not see), "position" (the rear
    # axle's (x, y)) and "brake" (the brake stopped the last step: a deterministic policy
    # that pushes into a parked car sees it was stopped). "slots" and "position" read the
    # env's position (agent.aids.observe_position), "brake" its brake (agent.aids.brake).
    # E.g. agent.features=[goal,clearance].
    features: list[str] = field(default_factory=list)
    # The past scans the "scan_memory" feature remembers.
    memory_scans: int = 3


@dataclass
class CurriculumConfig:
    levels: list[float] = field(default_factory=lambda: list(PAPER_LEVELS))
    frames_per_level: int = 2_000_000


@dataclass
class CollectorConfig:
    frames_per_batch: int = 2048
    total_frames: int = 12_000_000
    # torch.compile the policy inside the collector (torchrl's compile_policy): at thousands
    # of envs, the policy's TensorDict modules cost as much Python as the env's step.
    compile_policy: bool = False


@dataclass
class LossConfig:
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_epsilon: float = 0.2
    entropy_coef: float = 0.0
    critic_coef: float = 0.5
    mini_batch_size: int = 64
    ppo_epochs: int = 10
    reward_scale: float = 1.0  # rewards are multiplied by this before GAE and the critic



@dataclass
class OptimConfig:
    lr: float = 3e-4
    max_grad_norm: float = 0.5
    # torch.compile each PPO update (the loss, its backward pass, the gradient clipping and
    # Adam's step in one function), as torchrl's own recipes do; one rank only. It removes
    # the Python between kernels (docs/training.md: 1.3-1.46x per update of `fast` on the
    # CPU, after 15-40 s of compiling).
    compile_update: bool = False


@dataclass
class ModelConfig:
    hidden: list[int] = field(default_factory=lambda: [64, 64])
    init_log_std: float = 0.0
    # False: one learned log-std per action (SB3, the paper); True: the actor outputs it.
    state_dependent_std: bool = False
    # 0: every action is the TanhNormal's. An odd K >= 3 (a distilled gear-head student
    # only): each gear's steering is a choice among K bins spanning [-1, 1] with an offset
    # within the bin (trainers.heads.BinnedGearHead), fitted as a classification; PPO cannot
    # train it (the choice has no gradient).
    steer_bins: int = 0


@dataclass
class LoggerConfig:
    log_dir: str = "runs"
    exp_name: str = "ppo"
    checkpoint_every: int = 1_000_000  # frames


# torchrl's collector backends (``Collector(..., backend=...)``) dist.collectors may name.
# Not "distributed": torchrl 0.14's DistributedCollector reaches no worker-side state (its
# map_fn runs on the learner, its state_dict raises NotImplementedError), so the workers'
# normalisers could not be merged nor a checkpoint's state loaded into them; rpc starts its
# workers on the same torch.distributed launcher and reaches them.
COLLECTOR_BACKENDS = ("direct", "process", "ray", "rpc")


@dataclass
class DistConfig:
    """Where the run's work goes (README, "Scaling out"). The config's batch sizes and env
    count are global: each of ``world_size`` data-parallel ranks steps ``num_envs /
    world_size`` envs and trains on its share of every minibatch (gradients all-reduced), and
    each rank's collection is split over ``num_collectors`` workers of torchrl's backend."""

    # Data-parallel ranks (torch.distributed; launched by torchrun, or by the trainer itself).
    world_size: int = 1
    # "direct": the rank steps its envs itself; "process", "ray", "rpc": num_collectors
    # workers of torchrl's backend step them (COLLECTOR_BACKENDS).
    collectors: str = "direct"
    num_collectors: int = 1


@dataclass
class TrainConfig:
    env: EnvConfig = field(default_factory=EnvConfig)
    agent: AgentConfig = field(default_factory=AgentConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    dist: DistConfig = field(default_factory=DistConfig)
    seed: int = 0


def _fast() -> TrainConfig:
    """What a batched env allows: many compiled envs, short rollouts, a few epochs, and the
    agent-side aids that made the task learnable here (all documented in the README): each
    action held for 0.5 s (5 steps of dt), actions in [-1, 1], the goal seen from the car,
    half the training starts near the goal, an emergency brake that steers clear (its flag
    in the policy's input) and a docking layer under the policy, a state-dependent std,
    gamma 0.995, rewards x0.1 for the critic. Same reward, success test (4e-4) and 6-phase
    curriculum (2M frames = steps of dt per level) as the paper."""
    return TrainConfig(
        env=EnvConfig(num_envs=1024, compile_step=True),
        agent=AgentConfig(
            aids=AidsConfig(action_repeat=5, brake=BrakeConfig(steer_clear=5),
                            docking=DockingConfig(),
                            near_goal_starts=NearGoalStarts(probability=0.5)),
            action_exponents=[1.0, 1.0], features=["goal", "brake"]),
        collector=CollectorConfig(frames_per_batch=1024 * 32 * 5, compile_policy=True),
        loss=LossConfig(gamma=0.995, mini_batch_size=1024, ppo_epochs=8, reward_scale=0.1),
        model=ModelConfig(hidden=[256, 256], init_log_std=-1.0, state_dependent_std=True),
        logger=LoggerConfig(exp_name="fast"),
    )


def _gpu() -> TrainConfig:
    """``fast`` for one CUDA GPU: its batch and minibatch (163,840 frames, 1,024) from 4,096
    envs x 8 actions, the envs stepping and resetting in one compiled graph
    (``reset_in_step``, the host reading back once per batch), the policy and the PPO update
    compiled and Adam fused. The same agent, reward, success test and curriculum as
    ``fast``. A wider batch or minibatch makes fewer updates in the curriculum's 12M frames
    and learns less: 16,384 envs with minibatches of 8,192 trained at 1.04 M frames/s on an
    H200 and parked 0.13-0.30 (docs/training.md)."""
    cfg = _fast()
    return replace(cfg, env=EnvConfig(num_envs=4_096, device="cuda", compile_step=True),
                   optim=OptimConfig(compile_update=True),
                   logger=LoggerConfig(exp_name="gpu"))


def _smoke() -> TrainConfig:
    """A few thousand frames, under a minute: for tests and CI."""
    return TrainConfig(
        env=EnvConfig(num_envs=16, task=ParkingConfig(max_steps=50)),
        curriculum=CurriculumConfig(frames_per_level=1024),
        collector=CollectorConfig(frames_per_batch=16 * 64, total_frames=16 * 64 * 4),
        loss=LossConfig(mini_batch_size=256, ppo_epochs=2),
        logger=LoggerConfig(exp_name="smoke", checkpoint_every=2048),
    )


# The paper's own recipe runs on the paper's own tool chain (trainers.sb3_paper, which made
# results/paper/), not as a preset here: one way to run it.
PRESETS = {"fast": _fast, "gpu": _gpu, "smoke": _smoke}


def load_config(preset: str, overrides: list[str] | None = None) -> TrainConfig:
    """The preset's config with dot-notation overrides applied and checked."""
    return load_preset(PRESETS, preset, overrides, _check)


ConfigT = typing.TypeVar("ConfigT")


def load_preset(presets: dict[str, Callable[[], ConfigT]], preset: str,
                overrides: list[str] | None, check: Callable[[ConfigT], None]) -> ConfigT:
    """``presets[preset]``'s config (a recipe's) with dot-notation overrides applied, then
    ``check``-ed."""
    if preset not in presets:
        raise ValueError(f"preset must be one of {sorted(presets)}, got {preset!r}")
    cfg = override(presets[preset](), overrides or [])
    check(cfg)
    return cfg


def override(cfg: ConfigT, overrides: list[str]) -> ConfigT:
    """A copy of ``cfg`` (a config dataclass: a TrainConfig, a distiller's DistillConfig) with
    dot-notation overrides applied, their types checked (OmegaConf); a ValueError names the
    field of an unknown key or a wrong type. Ranges: the caller's."""
    try:
        given = OmegaConf.from_dotlist(overrides)
        check_flags(OmegaConf.to_container(given), type(cfg))
        merged = OmegaConf.merge(OmegaConf.structured(cfg), given)
        try:
            return OmegaConf.to_object(merged)
        except ValueError as err:  # a section's own check, in its class's words
            raise ValueError(by_dot_name(str(err), type(cfg), list(dotted(
                OmegaConf.to_container(given))))) from None
    except OmegaConfBaseException as err:  # a type error or an unknown key, by dot name
        key = getattr(err, "full_key", None)
        message = getattr(err, "msg", None) or str(err).splitlines()[0]
        raise ValueError(f"{key}: {message}" if key else message) from None


def sections(schema: type, prefix: str = "") -> dict[str, type]:
    """Every section of the config dataclass ``schema`` (optional ones included) by dot
    name: {"agent.aids": AidsConfig, ...}."""
    found: dict[str, type] = {}
    for name, kind in typing.get_type_hints(schema).items():
        nested = [k for k in (*typing.get_args(kind), kind) if dataclasses.is_dataclass(k)]
        if nested:
            found[f"{prefix}{name}"] = nested[0]
            found.update(sections(nested[0], f"{prefix}{name}."))
    return found


def by_dot_name(message: str, schema: type, given: list[str]) -> str:
    """A section's error (``"PlannerConfig.law_lateral must be ..."``) led by the field's dot
    name in ``schema`` (``"teacher.planner.law_lateral (PlannerConfig.law_lateral) must be
    ..."``): the section of that class, or of the sections of that class the one an
    override in ``given`` (dot names) set. Unchanged where neither tells."""
    owner, dot, rest = message.partition(".")
    field, space, tail = rest.partition(" ")
    places = [name for name, kind in sections(schema).items() if kind.__name__ == owner]
    if dot and len(places) > 1:
        places = [p for p in places if any(g == p or g.startswith(f"{p}.") for g in given)]
    if not dot or not space or len(places) != 1:
        return message
    return f"{places[0]}.{field} ({owner}.{field}) {tail}"


# The agent's features as they were saved before AgentConfig.features named them
# (2026-12-06): a flag (or scan_memory's count) per feature, appended in this order.
_FLAGGED_FEATURES = (("goal_features", "goal"), ("clearance_features", "clearance"),
                     ("gear_features", "gear"), ("scan_memory", "scan_memory"),
                     ("slot_features", "slots"), ("observe_position", "position"),
                     ("observe_brake", "brake"))


def upgraded_config(saved: dict) -> dict:
    """A saved run config (a checkpoint's) in today's fields: one saved with the agent's
    features as flags gets them as ``agent.features``, the same input in the same order
    (``aids.observe_position`` then also appended the position); ValueError naming a flag
    that holds anything else. Others come back as they are."""
    agent = saved.get("agent")
    if not isinstance(agent, dict) or "goal_features" not in agent:
        return saved
    agent = dict(agent)
    aids = agent.get("aids") if isinstance(agent.get("aids"), dict) else {}
    flags = {**agent, "observe_position": aids.get("observe_position", False)}
    for key, _ in _FLAGGED_FEATURES:
        value = flags.get(key, 0 if key == "scan_memory" else False)
        require(is_integer(value) and value >= 0 if key == "scan_memory"
                else isinstance(value, bool), f"agent.{key}",
                "an int >= 0" if key == "scan_memory" else "true or false", value)
    features = [name for key, name in _FLAGGED_FEATURES if flags.get(key)]
    scans = agent.get("scan_memory")
    for key, _ in _FLAGGED_FEATURES:
        agent.pop(key, None)
    agent["features"] = features
    if "scan_memory" in features:
        agent["memory_scans"] = scans
    return {**saved, "agent": agent}


def check_flags(values: dict, schema: type = TrainConfig, prefix: str = "") -> None:
    """ValueError naming the field where ``values`` (a nested dict of ``schema``'s fields)
    gives a bool field anything but true or false (an optional one: or null): OmegaConf would
    turn 2, "yes" or "on" into True, which torchpark's own configs refuse."""
    hints = typing.get_type_hints(schema)
    for key, value in values.items():
        kind = hints.get(key)
        nested = [k for k in (*typing.get_args(kind), kind) if dataclasses.is_dataclass(k)]
        if nested and isinstance(value, dict):  # a section, or an ``X | None`` of one
            check_flags(value, nested[0], f"{prefix}{key}.")
        elif kind is bool and not isinstance(value, bool):
            raise ValueError(f"{prefix}{key} must be true or false, got {value!r}")
        elif set(typing.get_args(kind)) == {bool, type(None)} and not (
                value is None or isinstance(value, bool)):
            raise ValueError(f"{prefix}{key} must be true, false or null, got {value!r}")


def dotted(values: object, name: str = "") -> dict[str, object]:
    """A nested dict of config fields (``dataclasses.asdict``) as {dot name: value}, under
    ``name`` (a None section is a value)."""
    if not isinstance(values, dict):
        return {name: values}
    return {k: v for key, value in values.items()
            for k, v in dotted(value, f"{name}.{key}" if name else key).items()}


def differences(saved: dict, now: dict, defaults: dict, free: tuple = ()
                ) -> list[tuple[str, object, object]]:
    """(dot name, saved value, value now) of each field where a run's saved config differs
    from this one's (nested dicts of config fields), leaving out the dot names in ``free``.
    A field the saved config lacks (added to the config after it was written) is its value
    in ``defaults``, which does what the code did before the field existed."""
    ours = dotted(now)
    theirs = {**dotted(defaults), **dotted(saved)}
    return [(k, theirs.get(k), ours.get(k)) for k in sorted(set(ours) | set(theirs))
            if theirs.get(k) != ours.get(k) and k not in free]


def has_field(schema: type, name: str) -> bool:
    """Whether the dot name ``name`` is a field of the config dataclass ``schema`` (through
    its sections, optional ones included)."""
    head, _, rest = name.partition(".")
    fields = {f.name for f in dataclasses.fields(schema)}
    if head not in fields:
        return False
    if not rest:
        return True
    kind = typing.get_type_hints(schema)[head]
    nested = [k for k in (*typing.get_args(kind), kind) if dataclasses.is_dataclass(k)]
    return bool(nested) and has_field(nested[0], rest)


def field_lines(cfg: object) -> str:
    """Every field of a config tree as ``dot.name = value`` lines (the preset's), for
    ``--help``."""
    return "\n".join(f"  {k} = {v!r}" for k, v in dotted(dataclasses.asdict(cfg)).items())


def env_configs(cfg: TrainConfig, training: bool) -> tuple[ParkingConfig, AidsConfig | None]:
    """The env's task and aids for this run: in training ``env.task`` and ``agent.aids`` as
    they are; in evaluation the same task with the paper's reward and success test, and the
    same aids without what only trains (near-goal starts, the brake's penalty). No aid at
    all: (task, None), the paper's env."""
    task, aids = cfg.env.task, cfg.agent.aids
    if not training:
        task = replace(task, reward=RewardConfig())
        aids = replace(aids, near_goal_starts=None, brake=None if aids.brake is None
                       else replace(aids.brake, penalty=0.0))
    return task, None if aids == AidsConfig() else aids


def _check(cfg: TrainConfig) -> None:
    """Every range the types do not already fix (OmegaConf checks those), by dot name."""
    finite = math.isfinite
    loss, c = cfg.loss, cfg.curriculum
    require(finite(loss.gamma) and 0 < loss.gamma <= 1, "loss.gamma", "in (0, 1]", loss.gamma)
    require(0 <= loss.gae_lambda <= 1, "loss.gae_lambda", "in [0, 1]", loss.gae_lambda)
    for name in ("clip_epsilon", "critic_coef", "reward_scale"):
        value = getattr(loss, name)
        require(finite(value) and value > 0, f"loss.{name}", "a finite number > 0", value)
    require(finite(cfg.optim.max_grad_norm) and cfg.optim.max_grad_norm > 0,
             "optim.max_grad_norm", "a finite number > 0", cfg.optim.max_grad_norm)
    require(finite(loss.entropy_coef) and loss.entropy_coef >= 0, "loss.entropy_coef",
             "a finite number >= 0", loss.entropy_coef)
    penalty = cfg.env.task.reward.collision_penalty
    require(penalty <= 0, "env.task.reward.collision_penalty", "<= 0 (a collision must not "
            "pay)", penalty)
    require(loss.ppo_epochs >= 1, "loss.ppo_epochs", "an int >= 1", loss.ppo_epochs)
    require(finite(cfg.optim.lr) and cfg.optim.lr > 0, "optim.lr", "a finite number > 0",
             cfg.optim.lr)
    check_model(cfg.model)
    require(cfg.model.steer_bins == 0, "model.steer_bins", "0 for PPO (a binned steering "
            "is chosen by an argmax, which has no gradient: a distilled student's only)",
            cfg.model.steer_bins)
    require(cfg.logger.checkpoint_every >= 1, "logger.checkpoint_every", "an int >= 1",
             cfg.logger.checkpoint_every)
    require(cfg.logger.exp_name not in ("", ".", "..") and "/" not in cfg.logger.exp_name,
             "logger.exp_name", "a folder name (no '/')", cfg.logger.exp_name)
    require(len(c.levels) >= 1 and all(0 <= v <= 1 for v in c.levels), "curriculum.levels",
             "a non-empty list of numbers in [0, 1]", c.levels)
    require(c.frames_per_level >= 1, "curriculum.frames_per_level", "an int >= 1",
             c.frames_per_level)
    check_seed(cfg.seed, "seed")
    check_device(cfg.env.device, "env.device")
    check_agent(cfg)
    n, batch, k = cfg.env.num_envs, cfg.collector.frames_per_batch, cfg.agent.aids.action_repeat
    if n < 1:
        raise ValueError(f"env.num_envs must be >= 1, got {n}")
    if batch < n * k or batch % (n * k):
        raise ValueError(f"collector.frames_per_batch must be a multiple of env.num_envs x "
                         f"agent.aids.action_repeat = {n * k}, got {batch}")
    require(cfg.collector.total_frames >= batch, "collector.total_frames",
             f">= collector.frames_per_batch = {batch}", cfg.collector.total_frames)
    if not 1 <= cfg.loss.mini_batch_size <= batch // k:
        raise ValueError(f"loss.mini_batch_size must be in [1, frames_per_batch / action_repeat"
                         f" = {batch // k}], got {cfg.loss.mini_batch_size}")
    _check_dist(cfg)


def check_model(model: ModelConfig, name: str = "model") -> None:
    """The network's sizes and first std (``name``: the section's dot name)."""
    require(len(model.hidden) >= 1 and min(model.hidden) >= 1, f"{name}.hidden",
            "a non-empty list of ints >= 1", model.hidden)
    # Beyond e^2 the TanhNormal's pre-tanh draws saturate (every action at a bound); beyond
    # e^88 its std overflows float32 and the first batch's actions are NaN.
    require(math.isfinite(model.init_log_std) and -20 <= model.init_log_std <= 2,
            f"{name}.init_log_std", "a number in [-20, 2] (the log of the policy's first "
            "std)", model.init_log_std)
    require(model.steer_bins == 0 or 3 <= model.steer_bins <= 255,
            f"{name}.steer_bins", "0, or an odd int in [3, 255]", model.steer_bins)


def check_agent(cfg: TrainConfig, prefix: str = "") -> None:
    """The agent's transforms against its aids (the aids' and the task's own fields are
    checked by their dataclasses as they are built); ``prefix``: the dot name of the run's
    config in a larger one (a distiller's ``student.``)."""
    agent = cfg.agent
    require(not agent.gear_head or agent.action_exponents is not None,
            f"{prefix}agent.gear_head", f"False without {prefix}agent.action_exponents (the "
            f"gear picks a pair of [-1, 1] actions for the power map)", agent.gear_head)
    exponents = agent.action_exponents
    require(exponents is None or (len(exponents) == 2
                                  and all(1.0 <= e <= 8.0 for e in exponents)),
            f"{prefix}agent.action_exponents", "null or two numbers in [1, 8] (speed, steer)",
            exponents)
    names = ", ".join(FEATURES)
    require(all(name in FEATURES for name in agent.features)
            and len(set(agent.features)) == len(agent.features),
            f"{prefix}agent.features", f"a list of distinct names among {names}",
            agent.features)
    outputs = {POSITION: ("aids.observe_position", agent.aids.observe_position),
               BRAKED: ("aids.brake", agent.aids.brake is not None)}
    for name in agent.features:
        for key in FEATURES[name].reads:
            aid, on = outputs[key]
            require(on, f"{prefix}agent.features", f"without {name!r} unless "
                    f"{prefix}agent.{aid} is on (it reads the env's {key!r})", agent.features)
    require(1 <= agent.memory_scans <= 64, f"{prefix}agent.memory_scans",
            "an int in [1, 64] (past scans the scan memory holds)", agent.memory_scans)
    bins = cfg.model.steer_bins
    require(bins == 0 or (bins >= 3 and bins % 2 == 1 and agent.gear_head),
            f"{prefix}model.steer_bins", f"0, or an odd int >= 3 with {prefix}agent.gear_head "
            f"(the bins steer each gear)", bins)


def _check_dist(cfg: TrainConfig) -> None:
    """The dist section against the sizes it splits."""
    d = cfg.dist
    require(d.world_size >= 1, "dist.world_size", "an int >= 1", d.world_size)
    require(d.world_size == 1 or not cfg.optim.compile_update, "optim.compile_update",
            "False with dist.world_size > 1 (the compiled update is one rank's)",
            cfg.optim.compile_update)
    require(d.collectors != "distributed", "dist.collectors", "direct, process, ray or rpc "
             "(torchrl 0.14's DistributedCollector reaches no worker-side state, so the "
             "workers' normalisers could not be kept consistent: use rpc)", d.collectors)
    require(d.collectors in COLLECTOR_BACKENDS, "dist.collectors",
             f"one of {list(COLLECTOR_BACKENDS)}", d.collectors)
    require(d.collectors != "ray" or importlib.util.find_spec("ray") is not None,
             "dist.collectors", "direct, process or rpc: ray needs Ray installed (pip install "
             "-e '.[ray]')", d.collectors)
    require(d.num_collectors >= 1, "dist.num_collectors", "an int >= 1", d.num_collectors)
    require(d.collectors != "direct" or d.num_collectors == 1, "dist.num_collectors",
             "1 with dist.collectors=direct (name a backend for several workers)",
             d.num_collectors)
    replicas = d.world_size * d.num_collectors
    require(cfg.env.num_envs % replicas == 0, "env.num_envs",
             f"a multiple of dist.world_size x dist.num_collectors = {replicas}",
             cfg.env.num_envs)
    require(cfg.loss.mini_batch_size % d.world_size == 0, "loss.mini_batch_size",
             f"a multiple of dist.world_size = {d.world_size} (each rank takes its share)",
             cfg.loss.mini_batch_size)



__all__ = ["PRESETS", "TrainConfig", "check_agent", "check_model", "differences", "dotted",
           "field_lines", "has_field", "load_config", "load_preset", "override", "replace"]
