"""PPO on torchpark with the occupancy curriculum, read top to bottom like torchrl's recipes.

    python -m trainers.ppo --preset fast [--resume CHECKPOINT] [key=value ...]

Overrides use the config's dot names, e.g. ``collector.total_frames=2000000 env.num_envs=256
logger.log_dir=/tmp/runs``.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from functools import partial
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE
from torchrl.record.loggers import TensorboardLogger
from tqdm import tqdm

from torchpark import OccupancyCurriculum
from torchpark.files import locked
from trainers.collection import RankCollection
from trainers.config import PRESETS, TrainConfig, load_config
from trainers.distributed import (
    World,
    all_gather,
    check_cores,
    data_parallel,
    gather_episodes,
    join,
    launch,
    launched,
    leave,
    standardise_advantage,
)
from trainers.runs import load_start, prepare, run_dir, save_run
from trainers.utils import build_models


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


def train(cfg: TrainConfig, resume: str | None = None, overwrite: bool = False,
          init: str | None = None) -> Path:
    """Run PPO; returns the path of the final checkpoint. The run directory is locked for
    the whole run (a second run into it is refused: ``torchpark.files.locked``); one that
    holds another run is refused unless ``overwrite``, whose files are deleted only once
    the run has checked and loaded everything (:func:`trainers.runs.check_log_dir`). ``init``: a
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
    if size > 1:
        check_cores(size, torch.device(cfg.env.device))  # before anything is written
    with locked(run_dir(cfg), "logger.log_dir"):
        stale = prepare(cfg, resume, overwrite, init)
        if size > 1:
            return launch(_launched_rank, (cfg, resume, init, stale), size,
                          torch.device(cfg.env.device))
        return _train(cfg, resume, World(device=torch.device(cfg.env.device)), init, stale)


def _launched_rank(cfg: TrainConfig, resume: str | None, init: str | None,
                   stale: list[Path]) -> Path:
    """A rank started by :func:`launch` (the run was checked, and is locked, by its
    parent)."""
    return _train(cfg, resume, join(cfg.dist.world_size, cfg.env.device), init, stale)


def _train(cfg: TrainConfig, resume: str | None, world: World, init: str | None,
           stale: list[Path]) -> Path:
    start = load_start(resume, init, world.device)
    frames, repeat = start.frames, cfg.agent.aids.action_repeat  # frames per env step
    remaining = cfg.collector.total_frames - frames
    if remaining < cfg.collector.frames_per_batch:
        raise ValueError(f"collector.total_frames={cfg.collector.total_frames} leaves less than "
                         f"one batch after the checkpoint's {frames} frames")
    torch.manual_seed(cfg.seed)  # the same initial networks on every rank

    # Models, loss, advantage, optimiser
    actor, critic = (m.to(world.device) for m in build_models(cfg))
    # normalize_advantage=False: ppo_step standardises over each minibatch of all ranks.
    loss_module = ClipPPOLoss(
        actor, critic, clip_epsilon=cfg.loss.clip_epsilon,
        entropy_bonus=cfg.loss.entropy_coef > 0, entropy_coeff=cfg.loss.entropy_coef,
        critic_coeff=cfg.loss.critic_coef, loss_critic_type="l2", normalize_advantage=False)
    advantage = GAE(gamma=cfg.loss.gamma, lmbda=cfg.loss.gae_lambda, value_network=critic,
                    average_gae=False)
    # One fused kernel per step on CUDA (torch's default there is one per op and tensor list).
    optim = torch.optim.Adam(loss_module.parameters(), lr=cfg.optim.lr,
                             fused=True if world.device.type == "cuda" else None)
    start.load_networks(actor, critic, optim, cfg)
    loss_fn = data_parallel(loss_module, world, cfg.seed)
    update = partial(ppo_step, loss_fn, optim, max_grad_norm=cfg.optim.max_grad_norm)
    if cfg.optim.compile_update:
        update = torch.compile(update)

    # Collector, its envs, the logger
    collection = RankCollection(cfg, actor, world, remaining)
    start.load_envs(collection, cfg, world)
    env, collector = collection.env, collection.collector
    if world.main:  # --overwrite: everything is loaded and built; the other run's files go
        for f in stale:
            f.unlink(missing_ok=True)
    logger = TensorboardLogger(exp_name=cfg.logger.exp_name, log_dir=cfg.logger.log_dir) \
        if world.main else None
    curriculum = next(t for t in env.transform if isinstance(t, OccupancyCurriculum))
    mini_batch = cfg.loss.mini_batch_size // world.size  # each rank's share

    def save(name: str) -> Path:
        return save_run(run_dir(cfg) / name, cfg, frames, actor, critic, optim, collection,
                        world, start.started_from)

    # Main loop
    every = cfg.logger.checkpoint_every
    next_checkpoint = (frames // every + 1) * every
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
                for index in torch.randperm(flat.shape[0], device=world.device).split(mini_batch):
                    losses = update(flat[index])
            collector.update_policy_weights_()
            collection.sync_normalisers()
            ended = gather_episodes(batch, world)
            train_time = time.perf_counter() - train_start
            if world.main:
                # The last minibatch's losses, read back together (one sync on CUDA).
                tags = {"loss/objective": "loss_objective", "loss/critic": "loss_critic",
                        "loss/kl_approx": "kl_approx", "loss/clip_fraction": "clip_fraction"}
                last = torch.stack([losses[key].detach() for key in tags.values()]).tolist()
                scalars = {
                    **episode_stats(ended, repeat),
                    "curriculum/occupancy": curriculum.occupancy,
                    "curriculum/phase": curriculum.phase,
                    "curriculum/success_threshold": env.base_env.success_threshold,
                    **dict(zip(tags, last, strict=True)),
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
                next_checkpoint += every
            collect_start = time.perf_counter()
    final = save("checkpoint_final.pt")
    collection.shutdown()
    del update, loss_fn  # DDP goes before its process group (trainers.distributed.leave)
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
