"""PPO on torchpark with the occupancy curriculum, read top to bottom like torchrl's recipes.

    python -m trainers.ppo --preset fast [--resume CHECKPOINT] [key=value ...]

Overrides use the config's dot names, e.g. ``collector.total_frames=2000000 env.num_envs=256
logger.log_dir=/tmp/runs``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import time
from pathlib import Path

import torch
from tensordict import TensorDict
from torch.nn.parallel import DistributedDataParallel
from torchrl.collectors import Collector
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE
from torchrl.record.loggers import TensorboardLogger
from tqdm import tqdm

from torchpark import OccupancyCurriculum
from torchpark.files import locked, save_torch
from trainers.checkpoint import EVALUATION_KEYS, RESUME_KEYS, load_checkpoint, load_weights
from trainers.collection import RankCollection
from trainers.config import PRESETS, TrainConfig, load_config
from trainers.distributed import (
    World,
    all_gather,
    gather_episodes,
    gather_to_main,
    join,
    launch,
    launched,
    leave,
    rank_seed,
    standardise_advantage,
)
from trainers.utils import build_models, reset_exploration

# Config sections a checkpoint must share with the run that resumes it / starts from it.
_MODEL_SECTIONS = ("env", "agent", "train", "model", "curriculum")
_INIT_SECTIONS = ("agent", "model")
_INIT_FREE = ("model.init_log_std",)  # a started actor explores from the run's own std


def episode_stats(ended: TensorDict | None, repeat: int = 1) -> dict[str, float]:
    """Means over the episodes that ended in this batch (``next`` entries of the steps that
    ended them, ``trainers.distributed.gather_episodes``; empty dict when none did). Lengths
    in steps of dt: env steps x ``repeat`` (the action repeat; the last one may be cut short
    by the episode's end)."""
    if ended is None:
        return {}
    return {
        "episode/reward": ended["episode_reward"].mean().item(),
        "episode/length": ended["step_count"].float().mean().item() * repeat,
        "episode/success_rate": ended["success"].float().mean().item(),
        "episode/collision_rate": ended["collision"].float().mean().item(),
        "episode/timeout_rate": ended["truncated"].float().mean().item(),
        "episode/final_distance": ended["observation"][:, :2].norm(dim=-1).median().item(),
    }


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


def recompute_log_prob_(actor: torch.nn.Module, batch: TensorDict, key: str) -> None:
    """Replace the log-probability stored with each sampled action (``key``) by the one the
    loss will compute from the stored action, with the same (sampling) actor. A TanhNormal
    sample's log-probability comes from its pre-tanh draw, the loss's from the float32
    action, whose atanh is clamped near +-1: where the draw is saturated (pre-tanh beyond
    ~7) the two differ by hundreds of nats, and PPO's ratio with them is noise. Recomputed,
    the ratio is 1 before the first step, as PPO's trust region assumes."""
    with torch.no_grad():
        batch.set(key, actor.get_dist(batch).log_prob(batch["action"]).reshape(batch[key].shape))


def ppo_step(loss_fn: torch.nn.Module, optim: torch.optim.Optimizer, sample: TensorDict,
             max_grad_norm: float) -> TensorDict:
    """One gradient step of PPO on a minibatch (``sample``: this rank's share of it); returns
    the losses. ``loss_fn``: a ``ClipPPOLoss`` built with ``normalize_advantage=False``, or
    with several ranks the ``DistributedDataParallel`` around it, whose forward all-reduces
    the gradients. The advantages are standardised here, over the minibatch of all ranks
    (``standardise_advantage``), so every rank takes the step one process would take on the
    whole minibatch."""
    sample.set("advantage", standardise_advantage(sample["advantage"]))
    losses = loss_fn(sample)
    total = losses["loss_objective"] + losses["loss_critic"]
    if "loss_entropy" in losses.keys():
        total = total + losses["loss_entropy"]
    total.backward()
    params = [p for group in optim.param_groups for p in group["params"]]
    torch.nn.utils.clip_grad_norm_(params, max_grad_norm)
    optim.step()
    optim.zero_grad()
    return losses


def check_ranks_agree(modules: list[torch.nn.Module], world: World) -> None:
    """RuntimeError unless every rank holds the same parameters (a step that bypassed the
    gradients' all-reduce would part them): checked at each checkpoint."""
    if not world.parallel:
        return
    mine = torch.cat([p.detach().reshape(-1).cpu() for m in modules for p in m.parameters()])
    if not all(torch.equal(mine, other) for other in all_gather(mine, world)):
        raise RuntimeError("the ranks' networks differ: their gradients were not all-reduced")


def run_state(env, collector: Collector) -> dict:
    """What an exact resume needs beyond the networks, the optimiser and the transforms'
    statistics: every lot's state and the env's generator (``ParkingEnv.snapshot``), the
    collector's carried TensorDict (the next step's input: observation, step counts, episode
    rewards; not the collector's own trajectory ids, bookkeeping PPO does not read) and
    torch's random state (the policy's samples, the minibatch order)."""
    # The carrier is the collector's private attribute: torchrl 0.14 has no public accessor
    # and its own load_state_dict starts fresh trajectories (tests/test_trainer.py checks
    # that a resumed run equals an uninterrupted one, bit for bit).
    carrier = collector._carrier.exclude("collector")
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
    carrier = collector._carrier
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
    out the dot names in ``free``. A field the checkpoint lacks (added to the config after it
    was written) is its default, which does what the code did before the field existed."""
    now = dataclasses.asdict(getattr(cfg, section))
    old = {**dataclasses.asdict(getattr(TrainConfig(), section)),
           **saved.get(section, {})}
    return ", ".join(f"{section}.{k}={old.get(k)!r} in the checkpoint, {now.get(k)!r} now"
                     for k in sorted(set(old) | set(now))
                     if old.get(k) != now.get(k) and f"{section}.{k}" not in free)


def prepare(cfg: TrainConfig, resume: str | None, overwrite: bool, init: str | None = None
            ) -> list[Path]:
    """What is checked before any rank starts, in the run directory the caller has locked:
    the directory (:func:`check_log_dir`), that the checkpoint to resume was trained with the
    same task, agent and model, and that the checkpoint to start from (``init``) has the
    run's agent and model (its std may differ: the run's ``model.init_log_std`` replaces
    it). Returns the files of another run that ``overwrite`` replaces: deleted by the run
    once it has loaded everything it reads (:func:`_train`), not here."""
    if resume is not None and init is not None:
        raise ValueError("--resume continues a run and --init starts one: pass one of them")
    stale = check_log_dir(run_dir(cfg), resume, overwrite, reads=(resume, init))
    for path, keys, sections, free in ((resume, RESUME_KEYS, _MODEL_SECTIONS, ()),
                                       (init, EVALUATION_KEYS, _INIT_SECTIONS, _INIT_FREE)):
        if path is None:
            continue
        saved = load_checkpoint(path, "cpu", keys)["config"]
        for section in sections:
            listed = config_differences(saved, cfg, section, free)
            if listed:
                raise ValueError(f"checkpoint {path!r} was trained with another {section} "
                                 f"config: {listed}")
    return stale


def train(cfg: TrainConfig, resume: str | None = None, overwrite: bool = False,
          init: str | None = None) -> Path:
    """Run PPO; returns the path of the final checkpoint. The run directory is locked for
    the whole run (a second run into it is refused: ``torchpark.files.locked``); one that
    holds another run is refused unless ``overwrite``, whose files are deleted only once
    the run has checked and loaded everything (see :func:`check_log_dir`). ``init``: a
    checkpoint (e.g. a distilled student, ``trainers.distill``) whose actor's mean and
    observation statistics the run starts from, its std reset to ``model.init_log_std``
    (:func:`~trainers.utils.reset_exploration`) and the statistics frozen, with a fresh
    critic, optimiser and curriculum.

    ``dist.world_size`` > 1: data-parallel (``trainers.distributed``). Under a launcher
    (torchrun) this process is one rank and rank 0 locks and checks the run first; without
    one, the checks run here, under the lock, and torch's elastic agent starts the ranks.
    """
    size = cfg.dist.world_size
    if launched():
        world = join(size, cfg.env.device)
        with contextlib.ExitStack() as held:
            error, stale = None, []
            if world.main:
                try:
                    held.enter_context(locked(run_dir(cfg), "logger.log_dir"))
                    stale = prepare(cfg, resume, overwrite, init)
                except ValueError as err:
                    error = str(err)
            error = all_gather(error, world)[0]
            if error is not None:
                leave(world)
                raise ValueError(error)
            return _train(cfg, resume, world, init, stale)
    with locked(run_dir(cfg), "logger.log_dir"):
        stale = prepare(cfg, resume, overwrite, init)
        if size > 1:
            return launch(_launched_rank, (cfg, resume, init, stale), size)
        return _train(cfg, resume, World(device=torch.device(cfg.env.device)), init, stale)


def _launched_rank(cfg: TrainConfig, resume: str | None, init: str | None,
                   stale: list[Path]) -> Path:
    """A rank started by :func:`launch` (the run was checked, and is locked, by its
    parent)."""
    return _train(cfg, resume, join(cfg.dist.world_size, cfg.env.device), init, stale)


def _train(cfg: TrainConfig, resume: str | None, world: World, init: str | None,
           stale: list[Path]) -> Path:
    directory = run_dir(cfg)
    checkpoint = load_checkpoint(resume, world.device, RESUME_KEYS) if resume else None
    start = load_checkpoint(init, world.device) if init else None
    # What the actor started from, kept through resumes (the evaluator's "policy" column).
    started_from = checkpoint.get("started_from") if checkpoint is not None else init
    torch.manual_seed(cfg.seed)  # the same initial networks on every rank
    device = world.device
    frames = checkpoint["frames"] if checkpoint is not None else 0
    remaining = cfg.collector.total_frames - frames
    repeat = cfg.agent.action_repeat  # frames per env step
    if remaining < cfg.collector.frames_per_batch:
        raise ValueError(f"collector.total_frames={cfg.collector.total_frames} leaves less than "
                         f"one batch after the checkpoint's {frames} frames")

    actor, critic = build_models(cfg)
    actor, critic = actor.to(device), critic.to(device)
    # The advantages are standardised over each minibatch of all ranks by ppo_step.
    loss_module = ClipPPOLoss(
        actor, critic, clip_epsilon=cfg.loss.clip_epsilon,
        entropy_bonus=cfg.loss.entropy_coef > 0, entropy_coeff=cfg.loss.entropy_coef,
        critic_coeff=cfg.loss.critic_coef, loss_critic_type="l2", normalize_advantage=False)
    advantage = GAE(gamma=cfg.loss.gamma, lmbda=cfg.loss.gae_lambda, value_network=critic,
                    average_gae=False)
    optim = torch.optim.Adam(loss_module.parameters(), lr=cfg.optim.lr)
    if start is not None:
        load_weights(actor, start["actor"], init, "actor")
        reset_exploration(actor, cfg.model)
    if checkpoint is not None:
        for module, entry in ((actor, "actor"), (critic, "critic"), (optim, "optim")):
            load_weights(module, checkpoint[entry], resume, entry)
    # Only DDP's forward all-reduces the gradients: the loss is always computed through it.
    loss_fn = DistributedDataParallel(loss_module) if world.parallel else loss_module
    if world.parallel:  # each rank's own stream for the policy's samples, the minibatches
        torch.manual_seed(rank_seed(cfg.seed, world.rank, world.size))

    collection = RankCollection(cfg, actor, world, remaining)
    env, collector = collection.env, collection.collector
    exact = rank_states(checkpoint, cfg) if checkpoint is not None else None
    if checkpoint is None:
        if start is not None:
            collection.load_normaliser(start["obs_norm"])
        collection.spread_timeouts()
    else:
        collection.load_env_state(checkpoint["env"])
        if exact is not None:
            resume_state(exact[world.rank], env, collector)
        elif world.main:
            print(f"{resume}: no env state for {world.size} rank(s) with "
                  f"{cfg.dist.collectors} collection; resuming with fresh episodes")
    if started_from is not None:
        # The started actor's inputs stay on its own scale: a few batches of the new run's
        # statistics shift them enough to undo a millimetre-precise student.
        collection.freeze_normaliser()
    if world.main:  # --overwrite: everything is loaded and built; the other run's files go
        for f in stale:
            f.unlink(missing_ok=True)
    logger = TensorboardLogger(exp_name=cfg.logger.exp_name, log_dir=cfg.logger.log_dir) \
        if world.main else None
    curriculum = next(t for t in env.transform if isinstance(t, OccupancyCurriculum))
    mini_batch = cfg.loss.mini_batch_size // world.size  # each rank's share

    def save(name: str) -> Path:
        path = directory / name
        check_ranks_agree([actor, critic], world)
        states = None
        if collection.direct:
            states = gather_to_main(run_state(env, collector), world)
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

    next_checkpoint = (frames // cfg.logger.checkpoint_every + 1) * cfg.logger.checkpoint_every
    if cfg.env.compile_step and world.main:
        print("compiling the env's step and reset for the first batch (tens of seconds) ...",
              flush=True)
    with tqdm(total=cfg.collector.total_frames, initial=frames, unit="frame", smoothing=0.1,
              disable=not world.main) as bar:  # closed before any error is printed
        collect_start = time.perf_counter()
        for batch in collector:
            collect_time = time.perf_counter() - collect_start
            batch_frames = batch.numel() * repeat * world.size
            frames += batch_frames
            train_start = time.perf_counter()
            with torch.no_grad():
                advantage(batch)
            recompute_log_prob_(actor, batch, loss_module.tensor_keys.sample_log_prob)
            flat = batch.reshape(-1)
            for _ in range(cfg.loss.ppo_epochs):
                for index in torch.randperm(flat.shape[0], device=device).split(mini_batch):
                    losses = ppo_step(loss_fn, optim, flat[index], cfg.optim.max_grad_norm)
            collector.update_policy_weights_()
            collection.sync_normalisers()
            ended = gather_episodes(batch, world)
            train_time = time.perf_counter() - train_start

            if world.main:
                scalars = {
                    **episode_stats(ended, repeat),
                    "curriculum/occupancy": curriculum.occupancy,
                    "curriculum/phase": curriculum.phase,
                    "curriculum/success_threshold": env.base_env.success_threshold,
                    "loss/objective": losses["loss_objective"].item(),
                    "loss/critic": losses["loss_critic"].item(),
                    "loss/kl_approx": losses["kl_approx"].item(),
                    "loss/clip_fraction": losses["clip_fraction"].item(),
                    "time/collect_fps": batch_frames / collect_time,
                    "time/train_fps": batch_frames / train_time,
                    "time/fps": batch_frames / (collect_time + train_time),
                }
                for key, value in scalars.items():
                    logger.log_scalar(key, value, step=frames)
                bar.update(batch_frames)
                bar.set_postfix(phase=curriculum.phase,
                                success=f"{scalars.get('episode/success_rate', float('nan')):.2f}")
            if frames >= next_checkpoint:
                save(f"checkpoint_{frames}.pt")
                next_checkpoint += cfg.logger.checkpoint_every
            collect_start = time.perf_counter()
    final = save("checkpoint_final.pt")
    collection.shutdown()
    del loss_fn  # DDP's reducer goes before its process group
    leave(world)
    return final


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m trainers.ppo", description=__doc__)
    parser.add_argument("--preset", default="fast", help=", ".join(PRESETS))
    parser.add_argument("--resume", default=None, help="checkpoint to continue from")
    parser.add_argument("--init", default=None,
                        help="checkpoint whose actor and observation statistics a new run "
                             "starts from (its agent and model config must be the run's)")
    parser.add_argument("overrides", nargs="*", help="config fields as key=value")
    parser.add_argument("--overwrite", action="store_true",
                        help="delete the checkpoints and logs of a run already in the run's "
                             "directory (by default such a directory is refused)")
    args = parser.parse_intermixed_args(argv)
    try:
        path = train(load_config(args.preset, args.overrides), resume=args.resume,
                     overwrite=args.overwrite, init=args.init)
    except (ValueError, OSError) as err:
        parser.exit(2, f"{parser.prog}: error: {str(err).splitlines()[0]}\n")
    print(f"final checkpoint: {path}")


if __name__ == "__main__":
    main()
