"""A PPO run's directory and checkpoints: where it writes (checked and locked before it
starts), what it starts from (``--resume`` a checkpoint of the same config, ``--init`` a
checkpoint's actor), and what a checkpoint holds so that a resumed run goes on exactly as
if it had not stopped. ``trainers.ppo`` calls :func:`prepare`, :func:`load_start`,
:meth:`Start.load_networks`, :meth:`Start.load_envs` and :func:`save_run`."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import NamedTuple

import torch
from torchrl.collectors import Collector

from torchpark._compat import collector_carrier
from torchpark.files import save_torch
from trainers.checkpoint import EVALUATION_KEYS, RESUME_KEYS, load_checkpoint, load_weights
from trainers.collection import RankCollection
from trainers.config import TrainConfig, differences
from trainers.distributed import World, check_ranks_agree, gather_to_main
from trainers.utils import reset_exploration

# Config sections a checkpoint must share with the run that resumes it / starts from it.
MODEL_SECTIONS = ("env", "agent", "model", "curriculum")
INIT_SECTIONS = ("agent", "model")
INIT_FREE = ("model.init_log_std",)  # a started actor explores from the run's own std


# What a run writes into its directory (logger.log_dir / logger.exp_name).
RUN_FILES = ("checkpoint_*.pt", "events.out.tfevents.*")


def run_dir(cfg: TrainConfig) -> Path:
    return Path(cfg.logger.log_dir) / cfg.logger.exp_name


def check_log_dir(path: Path, resume: str | None, overwrite: bool,
                  reads: tuple[str | None, ...] = ()) -> list[Path]:
    """The files of another run in the run directory ``path`` (made and locked by the
    caller) that this run replaces: none when it holds none, or when this run resumes a
    checkpoint from it (it goes on with that run); with ``overwrite``, the files a later
    step deletes once every check of the run has passed (never one of the files the run
    ``reads``); otherwise a ValueError."""
    existing = sorted(f for pattern in RUN_FILES for f in path.glob(pattern))
    continues = resume is not None and Path(resume).resolve().parent == path.resolve()
    if not existing or continues:
        return []
    if not overwrite:
        raise ValueError(f"{str(path)!r} already holds a run ({len(existing)} files, e.g. "
                         f"{existing[0].name}): choose another logger.exp_name or "
                         f"logger.log_dir, --resume one of its checkpoints, or pass "
                         f"--overwrite to delete them")
    kept = {Path(p).resolve() for p in reads if p is not None}
    return [f for f in existing if f.resolve() not in kept]


def run_state(env, collector: Collector) -> dict:
    """What an exact resume needs beyond the networks, the optimiser and the transforms'
    statistics: every lot's state and the env's generator (``ParkingEnv.snapshot``), the
    collector's carried TensorDict (the next step's input: observation, step counts, episode
    rewards; not the collector's own trajectory ids, bookkeeping PPO does not read) and
    torch's random state (the policy's samples, the minibatch order)."""
    # The carrier is the collector's private attribute (torchpark._compat): torchrl 0.14 has
    # no public accessor and its own load_state_dict starts fresh trajectories
    # (tests/test_trainer.py checks that a resumed run equals an uninterrupted one, bit for
    # bit).
    carrier = collector_carrier(collector).exclude("collector")
    state = {"sim": env.base_env.snapshot(), "carrier": carrier.to_dict(),
             "rng": torch.get_rng_state()}
    if torch.device(env.device).type == "cuda":
        state["cuda_rng"] = torch.cuda.get_rng_state(env.device)
    return state


def resume_state(state: dict, env, collector: Collector) -> None:
    """Put the env, the collector and torch's random state where a rank of the checkpoint's
    run was (after the collector's own reset, which would otherwise have moved them);
    ``state`` is that rank's :func:`run_state`."""
    env.base_env.restore(state["sim"])
    carrier = collector_carrier(collector)
    carrier.update(type(carrier).from_dict(state["carrier"], batch_size=carrier.batch_size,
                                           device=carrier.device))
    torch.set_rng_state(state["rng"])
    if "cuda_rng" in state:
        torch.cuda.set_rng_state(state["cuda_rng"], env.device)


def rank_states(checkpoint: dict, cfg: TrainConfig) -> list[dict] | None:
    """The per-rank run states of a checkpoint, when this run can continue them exactly:
    written with direct collection by as many ranks as this run has (one rank: the
    top-level ``sim`` / ``carrier`` / ``rng``; K ranks: ``ranks``)."""
    if cfg.dist.collectors != "direct":
        return None
    states = checkpoint.get("ranks") or ([checkpoint] if "sim" in checkpoint else None)
    if states is None or len(states) != cfg.dist.world_size:
        return None
    return states


def config_differences(saved: dict, cfg: TrainConfig, section: str, free: tuple = ()) -> str:
    """The fields of ``cfg``'s ``section`` that differ from a checkpoint's saved config, as
    ``"section.field=<saved> in the checkpoint, <now> now"`` (empty when none do), leaving
    out the dot names in ``free`` (:func:`trainers.config.differences`)."""
    return ", ".join(f"{k}={old!r} in the checkpoint, {now!r} now" for k, old, now in
                     differences({section: saved.get(section, {})},
                             {section: dataclasses.asdict(getattr(cfg, section))},
                             {section: dataclasses.asdict(getattr(TrainConfig(), section))},
                             free))


def prepare(cfg: TrainConfig, resume: str | None, overwrite: bool, init: str | None = None
            ) -> list[Path]:
    """What is checked before any rank starts, in the run directory the caller has locked:
    the directory (:func:`check_log_dir`), that the checkpoint to resume was trained with the
    same task, agent and model, and that the checkpoint to start from (``init``) has the
    run's agent and model (its std may differ: the run's ``model.init_log_std`` replaces
    it). Returns the files of another run that ``overwrite`` replaces: deleted by the run
    once it has loaded everything it reads (``trainers.ppo``), not here."""
    if resume is not None and init is not None:
        raise ValueError("--resume continues a run and --init starts one: pass one of them")
    stale = check_log_dir(run_dir(cfg), resume, overwrite, reads=(resume, init))
    for path, keys, sections, free in ((resume, RESUME_KEYS, MODEL_SECTIONS, ()),
                                       (init, EVALUATION_KEYS, INIT_SECTIONS, INIT_FREE)):
        if path is None:
            continue
        saved = load_checkpoint(path, "cpu", keys)["config"]
        for section in sections:
            listed = config_differences(saved, cfg, section, free)
            if listed:
                raise ValueError(f"checkpoint {path!r} was trained with another {section} "
                                 f"config: {listed}")
    return stale


class Start(NamedTuple):
    """What a run starts from: nothing, a checkpoint it resumes (``resume``, its contents
    ``checkpoint``) or one whose actor it starts from (``init``, ``initial``)."""

    resume: str | None
    checkpoint: dict | None
    init: str | None
    initial: dict | None

    @property
    def frames(self) -> int:
        """Frames already trained (the resumed checkpoint's)."""
        return self.checkpoint["frames"] if self.checkpoint is not None else 0

    @property
    def started_from(self) -> str | None:
        """The checkpoint the actor started from, kept through resumes (the evaluator's
        "policy" column)."""
        return self.checkpoint.get("started_from") if self.checkpoint is not None else self.init

    def load_networks(self, actor: torch.nn.Module, critic: torch.nn.Module,
                      optim: torch.optim.Optimizer, cfg: TrainConfig) -> None:
        """The resumed checkpoint's actor, critic and optimiser, or the started-from actor
        with its std reset to ``model.init_log_std``."""
        if self.initial is not None:
            load_weights(actor, self.initial["actor"], self.init, "actor")
            reset_exploration(actor, cfg.model)
        if self.checkpoint is not None:
            for module, entry in ((actor, "actor"), (critic, "critic"), (optim, "optim")):
                load_weights(module, self.checkpoint[entry], self.resume, entry)

    def load_envs(self, collection: RankCollection, cfg: TrainConfig, world: World) -> None:
        """The envs where the resumed run's were (exactly, where it ran on as many ranks
        with direct collection; else fresh episodes with its curriculum and normaliser), or
        fresh ones with the started-from normaliser; timeouts spread over a fresh run's
        first episodes. A started actor's inputs stay on its own scale (the normaliser
        frozen): a few batches of the new run's statistics shift them enough to undo a
        millimetre-precise student."""
        if self.checkpoint is None:
            if self.initial is not None:
                collection.load_normaliser(self.initial["obs_norm"])
            collection.spread_timeouts()
        else:
            collection.load_env_state(self.checkpoint["env"])
            exact = rank_states(self.checkpoint, cfg)
            if exact is not None:
                resume_state(exact[world.rank], collection.env, collection.collector)
            elif world.main:
                print(f"{self.resume}: no env state for {world.size} rank(s) with "
                      f"{cfg.dist.collectors} collection; resuming with fresh episodes")
        if self.started_from is not None:
            collection.freeze_normaliser()


def load_start(resume: str | None, init: str | None, device: torch.device) -> Start:
    """The checkpoints a run starts from (checked by :func:`prepare`), on ``device``."""
    return Start(resume, load_checkpoint(resume, device, RESUME_KEYS) if resume else None,
                 init, load_checkpoint(init, device) if init else None)


def save_run(path: Path, cfg: TrainConfig, frames: int, actor: torch.nn.Module,
             critic: torch.nn.Module, optim: torch.optim.Optimizer,
             collection: RankCollection, world: World, started_from: str | None) -> Path:
    """Write the run's checkpoint (rank 0; every rank takes part in gathering the ranks'
    run states): config, frames, networks, optimiser, the transforms' state, the
    observation normaliser and, with direct collection, what an exact resume needs
    (:func:`run_state`, per rank)."""
    check_ranks_agree([actor, critic], world)
    env = collection.env
    states = gather_to_main(run_state(env, collection.collector), world) \
        if collection.direct else None
    if not world.main:
        return path
    state = {"config": dataclasses.asdict(cfg), "frames": frames,
             "actor": actor.state_dict(), "critic": critic.state_dict(),
             "optim": optim.state_dict(), "env": env.state_dict(),
             "obs_norm": env.transform[-1].state_dict()}
    if states is not None:
        state.update(states[0] if len(states) == 1 else {"ranks": states})
    if started_from is not None:
        state["started_from"] = started_from
        state["trained_by"] = (f"PPO ({cfg.logger.exp_name} run, {frames:,} frames) "
                               f"from {started_from}")
    return save_torch(state, path)
