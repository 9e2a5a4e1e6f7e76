"""Where a rank's frames come from: its own env (``dist.collectors=direct``) or
``dist.num_collectors`` workers of one of torchrl's collector backends (``process``, ``ray``,
``rpc``, ``distributed``: ``torchrl.collectors.Collector(..., backend=...)``), and the
worker-side state the learner keeps consistent.

Each worker steps ``env.num_envs / (world_size x num_collectors)`` lots built by
:func:`trainers.utils.make_env` from its own seed (workers start by spawn: the factory is a
picklable ``functools.partial`` of an importable function); ``sync=True`` (PPO is on-policy); the
total frames are finite (an endless run yields no batch on ray / rpc / distributed). The
curriculum in each worker counts the run's global frames (``replicas``); after each batch
the learner merges the workers' observation normalisers (``sync_normalisers``) and pushes
the merged statistics back, and it spreads the first timeouts in every worker.
"""

from __future__ import annotations

import functools
import os
import socket
from typing import Any

import torch
from torchrl.collectors import Collector

from trainers.config import TrainConfig
from trainers.distributed import World, all_gather, merge_normalisers, norm_counts, rank_seed
from trainers.utils import make_env


def free_port() -> int:
    """A TCP port on this machine that nothing listens on now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def backend_options(cfg: TrainConfig) -> dict[str, Any]:
    """``Collector(..., backend_options=...)`` for ``dist.collectors``: the policy compiled in
    each worker (``collector.compile_policy``); rpc and distributed workers started as local
    processes on a free port (their default launcher is submitit, for SLURM); Ray started on
    this machine's cores unless ``RAY_ADDRESS`` names a running cluster."""
    compile_policy = {"compile_policy": True} if cfg.collector.compile_policy else {}
    backend = cfg.dist.collectors
    if backend == "process":
        return compile_policy
    options: dict[str, Any] = {"collector_kwargs": compile_policy}
    if backend == "ray":
        if "RAY_ADDRESS" not in os.environ:
            options["ray_init_config"] = {"num_cpus": os.cpu_count(),
                                          "include_dashboard": False,
                                          "object_store_memory": 100_000_000}
        return options
    return {**options, "launcher": "mp", "tcp_port": str(free_port())}


class RankCollection:
    """A rank's collector and the envs behind it.

    ``env`` is the rank's own training env: with ``collectors=direct`` the collector steps
    it; with a backend it steps nothing (it gives the specs and holds the state a checkpoint
    saves: the curriculum's frames and the merged normaliser, copied from the workers after
    each batch).
    """

    def __init__(self, cfg: TrainConfig, actor: Any, world: World, remaining_frames: int
                 ) -> None:
        d = cfg.dist
        self.cfg, self.world, self.backend = cfg, world, d.collectors
        self.workers = d.num_collectors
        replicas = d.world_size * d.num_collectors
        num_envs = cfg.env.num_envs // replicas
        repeat = cfg.agent.aids.action_repeat
        # Env steps per rank: the collector counts steps, frames are steps of dt.
        steps_per_batch = cfg.collector.frames_per_batch // repeat // d.world_size
        total_steps = remaining_frames // repeat // d.world_size
        self.direct = d.collectors == "direct"
        if self.direct:
            self.env = make_env(cfg, num_envs=num_envs,
                                seed=rank_seed(cfg.seed, world.rank, d.world_size),
                                replicas=d.world_size)
            # No trajectory ids (nothing here reads them): torchrl reads done.any() back at
            # every step to count them.
            self.collector = Collector(self.env, actor, frames_per_batch=steps_per_batch,
                                       total_frames=total_steps, device=world.device,
                                       compile_policy=cfg.collector.compile_policy,
                                       track_traj_ids=False)
        else:
            seeds = [rank_seed(cfg.seed, world.rank * self.workers + w, replicas)
                     for w in range(self.workers)]
            factories = [functools.partial(make_env, cfg, num_envs=num_envs, seed=seed,
                                           replicas=replicas) for seed in seeds]
            # The learner's env: specs and the state a checkpoint saves (never stepped).
            self.env = make_env(cfg, num_envs=num_envs, seed=seeds[0], replicas=replicas)
            self.collector = Collector(factories, actor, backend=d.collectors,
                                       num_collectors=self.workers, sync=True,
                                       frames_per_batch=steps_per_batch,
                                       total_frames=total_steps, device=world.device,
                                       backend_options=backend_options(cfg))
        # The workers start from the learner's weights (Ray's collector asks for a first
        # sync before it is iterated).
        self.collector.update_policy_weights_()
        self._norm_prefix = f"transforms.{len(self.env.transform) - 1}."
        self._counted: dict[str, torch.Tensor] | None = None

    # -------------------------------------------------------------- worker-side state
    def call(self, path: str, *args: Any) -> list[Any]:
        """``path(*args)`` in each worker (``path`` from the worker's collector, e.g.
        ``"env.base_env.randomize_step_counts"``), in worker order: torchrl's ``map_fn``
        (process, ray) or the workers' remote references (rpc, whose ``map_fn`` runs on the
        learner)."""
        if self.backend == "rpc":
            return [rref.rpc_sync().cascade_execute(path, *args)
                    for rref in self.collector.collector_rrefs]
        return self.collector.map_fn(path, list_of_args=[args] * self.workers)

    def spread_timeouts(self) -> None:
        """Spread the first timeouts over [1, max_steps] steps in every replica (after the
        collectors' own reset)."""
        if self.direct:
            self.env.base_env.randomize_step_counts()
        else:
            self.call("env.base_env.randomize_step_counts")

    def load_env_state(self, state: dict) -> None:
        """Load a checkpoint's env state (curriculum frames, normaliser) into every replica."""
        self.env.load_state_dict(state)
        if not self.direct:
            self.call("env.load_state_dict", state)
        # Every replica starts from these counts: the next merge adds only what they see.
        self._counted = norm_counts(self._norm_state(state))

    def load_normaliser(self, state: dict) -> None:
        """Load observation statistics (a checkpoint's ``obs_norm``) into every replica."""
        self.env.transform[-1].load_state_dict(state)
        if not self.direct:
            self.call("env.transform[-1].load_state_dict", state)
        self._counted = norm_counts(state)

    def freeze_normaliser(self) -> None:
        """Stop every replica's observation statistics from moving (a network started from a
        checkpoint reads its inputs on the scale it was trained on)."""
        self.env.transform[-1].freeze()
        if not self.direct:
            self.call("env.transform[-1].freeze")

    def sync_normalisers(self) -> None:
        """Merge the observation normalisers of every replica of the run (all workers of all
        ranks, ``trainers.distributed.merge_normalisers``) and load the merged statistics in
        each; with a backend, the learner's env takes the first worker's state (its
        curriculum) with the merged normaliser. Nothing to merge in a one-env run."""
        if self.direct and not self.world.parallel:
            return
        if self.direct:
            states = [self.env.state_dict()]
        else:
            states = self.call("env.state_dict")
        norms = [self._norm_state(s) for s in states]
        gathered = [n for rank in all_gather(norms, self.world) for n in rank]
        merged = merge_normalisers(gathered, self._counted)
        self._counted = norm_counts(merged)
        if self.direct:
            self.env.transform[-1].load_state_dict(merged)
            return
        self.call("env.transform[-1].load_state_dict", merged)
        first = dict(states[0])
        first.update({self._norm_prefix + k: v for k, v in merged.items()})
        self.env.load_state_dict(first)

    def _norm_state(self, state: dict) -> dict:
        prefix = self._norm_prefix
        norm: dict = {}
        for key, value in state.items():
            if key.startswith(prefix):
                norm[key[len(prefix):]] = value
        return norm

    def shutdown(self) -> None:
        self.collector.shutdown()
