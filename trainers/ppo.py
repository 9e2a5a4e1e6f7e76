"""PPO on torchpark with the occupancy curriculum, read top to bottom like torchrl's recipes.

    python -m trainers.ppo --preset fast [--resume CHECKPOINT] [key=value ...]

Overrides use the config's dot names, e.g. ``collector.total_frames=2000000 env.num_envs=256
logger.log_dir=/tmp/runs``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE
from torchrl.record.loggers import TensorboardLogger
from tqdm import tqdm

from torchpark import OccupancyCurriculum
from trainers.checkpoint import RESUME_KEYS, load_checkpoint
from trainers.config import TrainConfig, load_config, upgrade_saved
from trainers.utils import NORMALISED, make_env, make_ppo_models

# Config sections a checkpoint must share with the run that resumes it.
_MODEL_SECTIONS = ("env", "agent", "train", "model", "curriculum")


def episode_stats(batch: TensorDict, repeat: int = 1) -> dict[str, float]:
    """Means over the episodes that ended in this batch (empty dict when none did). Lengths
    in steps of dt: env steps x ``repeat`` (the action repeat; the last one may be cut short
    by the episode's end)."""
    nxt = batch["next"]
    done = nxt["done"][..., 0]
    if not bool(done.any()):
        return {}
    return {
        "episode/reward": nxt["episode_reward"][done].mean().item(),
        "episode/length": nxt["step_count"][done].float().mean().item() * repeat,
        "episode/success_rate": nxt["success"][done].float().mean().item(),
        "episode/collision_rate": nxt["collision"][done].float().mean().item(),
        "episode/timeout_rate": nxt["truncated"][done].float().mean().item(),
        "episode/final_distance": nxt["observation"][done][:, :2].norm(dim=-1).median().item(),
    }


# What a run writes into its directory (logger.log_dir / logger.exp_name).
RUN_FILES = ("checkpoint_*.pt", "events.out.tfevents.*")


def check_log_dir(path: Path, resume: str | None, overwrite: bool) -> None:
    """Make the run directory; refuse one that holds another run's files, unless this run
    resumes a checkpoint from it (it goes on with that run) or ``overwrite`` (they are
    deleted)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"logger.log_dir {str(path)!r} cannot be created: {err}") from err
    if not os.access(path, os.W_OK):
        raise ValueError(f"logger.log_dir {str(path)!r} is not writable")
    existing = sorted(f for pattern in RUN_FILES for f in path.glob(pattern))
    continues = resume is not None and Path(resume).resolve().parent == path.resolve()
    if not existing or continues:
        return
    if not overwrite:
        raise ValueError(f"{str(path)!r} already holds a run ({len(existing)} files, e.g. "
                         f"{existing[0].name}): choose another logger.exp_name or "
                         f"logger.log_dir, --resume one of its checkpoints, or pass "
                         f"--overwrite to delete them")
    for f in existing:
        f.unlink()


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


def resume_state(checkpoint: dict, env, collector: Collector, path: str) -> None:
    """Put the env, the collector and torch's random state where the checkpoint's run was
    (after the collector's own reset, which would otherwise have moved them)."""
    env.load_state_dict(checkpoint["env"])
    if "sim" not in checkpoint:  # written before exact resumes: new episodes from here
        print(f"{path}: no env snapshot (an older checkpoint); resuming with fresh episodes")
        return
    env.base_env.restore(checkpoint["sim"])
    carrier = collector._carrier
    carrier.update(type(carrier).from_dict(checkpoint["carrier"], batch_size=carrier.batch_size,
                                           device=carrier.device))
    torch.set_rng_state(checkpoint["rng"])
    if "cuda_rng" in checkpoint:
        torch.cuda.set_rng_state(checkpoint["cuda_rng"], env.device)


def train(cfg: TrainConfig, resume: str | None = None, overwrite: bool = False) -> Path:
    """Run PPO; returns the path of the final checkpoint. A run directory that holds another
    run is refused unless ``overwrite`` (see :func:`check_log_dir`)."""
    run_dir = Path(cfg.logger.log_dir) / cfg.logger.exp_name
    check_log_dir(run_dir, resume, overwrite)
    checkpoint = load_checkpoint(resume, cfg.env.device, RESUME_KEYS) if resume else None
    if checkpoint is not None:
        saved = upgrade_saved(checkpoint["config"])
        for section in _MODEL_SECTIONS:
            now = dataclasses.asdict(getattr(cfg, section))
            old = saved.get(section, {})
            differ = {f"{section}.{k}": (old.get(k), now.get(k))
                      for k in sorted(set(old) | set(now)) if old.get(k) != now.get(k)}
            if differ:
                listed = ", ".join(f"{k}={a!r} in the checkpoint, {b!r} now"
                                   for k, (a, b) in differ.items())
                raise ValueError(f"checkpoint {resume!r} was trained with another {section} "
                                 f"config: {listed}")
    torch.manual_seed(cfg.seed)

    env = make_env(cfg)
    device = torch.device(cfg.env.device)
    actor, critic = make_ppo_models(env.observation_spec[NORMALISED].shape[-1], env.action_spec,
                                    cfg.model)
    actor, critic = actor.to(device), critic.to(device)
    loss_module = ClipPPOLoss(
        actor, critic, clip_epsilon=cfg.loss.clip_epsilon,
        entropy_bonus=cfg.loss.entropy_coef > 0, entropy_coeff=cfg.loss.entropy_coef,
        critic_coeff=cfg.loss.critic_coef, loss_critic_type="l2", normalize_advantage=True,
    )
    advantage = GAE(gamma=cfg.loss.gamma, lmbda=cfg.loss.gae_lambda, value_network=critic,
                    average_gae=False)
    optim = torch.optim.Adam(loss_module.parameters(), lr=cfg.optim.lr)
    frames = 0
    if checkpoint is not None:
        actor.load_state_dict(checkpoint["actor"])
        critic.load_state_dict(checkpoint["critic"])
        optim.load_state_dict(checkpoint["optim"])
        frames = checkpoint["frames"]
    remaining = cfg.collector.total_frames - frames
    repeat = cfg.agent.action_repeat  # frames per env step
    if remaining < cfg.collector.frames_per_batch:
        raise ValueError(f"collector.total_frames={cfg.collector.total_frames} leaves less than "
                         f"one batch after the checkpoint's {frames} frames")

    # The collector counts env steps; frames are steps of dt.
    collector = Collector(env, actor, frames_per_batch=cfg.collector.frames_per_batch // repeat,
                          total_frames=remaining // repeat, device=cfg.env.device,
                          compile_policy=cfg.collector.compile_policy)
    if checkpoint is None:
        # After the collector's reset: spread the first timeouts over [1, max_steps] steps.
        env.base_env.randomize_step_counts()
    else:
        resume_state(checkpoint, env, collector, resume)
    logger = TensorboardLogger(exp_name=cfg.logger.exp_name, log_dir=cfg.logger.log_dir)
    curriculum = next(t for t in env.transform if isinstance(t, OccupancyCurriculum))

    def save(name: str) -> Path:
        path = run_dir / name
        torch.save({"config": dataclasses.asdict(cfg), "frames": frames,
                    "actor": actor.state_dict(), "critic": critic.state_dict(),
                    "optim": optim.state_dict(), "env": env.state_dict(),
                    "obs_norm": env.transform[-1].state_dict(), **run_state(env, collector)},
                   path)
        return path

    next_checkpoint = (frames // cfg.logger.checkpoint_every + 1) * cfg.logger.checkpoint_every
    if cfg.env.compile_step:
        print("compiling the env's step and reset for the first batch (tens of seconds) ...",
              flush=True)
    bar = tqdm(total=cfg.collector.total_frames, initial=frames, unit="frame", smoothing=0.1)
    collect_start = time.perf_counter()
    for batch in collector:
        collect_time = time.perf_counter() - collect_start
        batch_frames = batch.numel() * repeat
        frames += batch_frames
        train_start = time.perf_counter()
        with torch.no_grad():
            advantage(batch)
        flat = batch.reshape(-1)
        for _ in range(cfg.loss.ppo_epochs):
            for index in torch.randperm(flat.shape[0], device=device).split(
                    cfg.loss.mini_batch_size):
                losses = loss_module(flat[index])
                total = losses["loss_objective"] + losses["loss_critic"]
                if "loss_entropy" in losses.keys():
                    total = total + losses["loss_entropy"]
                total.backward()
                torch.nn.utils.clip_grad_norm_(loss_module.parameters(), cfg.optim.max_grad_norm)
                optim.step()
                optim.zero_grad()
        collector.update_policy_weights_()
        train_time = time.perf_counter() - train_start

        scalars = {
            **episode_stats(batch, repeat),
            "curriculum/occupancy": curriculum.occupancy, "curriculum/phase": curriculum.phase,
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
    bar.close()
    final = save("checkpoint_final.pt")
    collector.shutdown()
    return final


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m trainers.ppo", description=__doc__)
    parser.add_argument("--preset", default="fast", help="paper, fast or smoke")
    parser.add_argument("--resume", default=None, help="checkpoint to continue from")
    parser.add_argument("overrides", nargs="*", help="config fields as key=value")
    parser.add_argument("--overwrite", action="store_true",
                        help="delete the checkpoints and logs of a run already in the run's "
                             "directory (by default such a directory is refused)")
    args = parser.parse_intermixed_args(argv)
    try:
        path = train(load_config(args.preset, args.overrides), resume=args.resume,
                     overwrite=args.overwrite)
    except ValueError as err:
        parser.exit(2, f"{parser.prog}: error: {str(err).splitlines()[0]}\n")
    print(f"final checkpoint: {path}")


if __name__ == "__main__":
    main()
