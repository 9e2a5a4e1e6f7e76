"""Data-parallel PPO on torch.distributed: the process group, the launch, and what the ranks
share.

Each of ``dist.world_size`` ranks steps its own envs (``env.num_envs / world_size``, its own
seed) and trains on its share of every minibatch; ``DistributedDataParallel`` around the loss
all-reduces the gradients, so all ranks take the update one process would take on the global
minibatch. The advantages of a minibatch are standardised with moments over all ranks
(:func:`standardise_advantage`); the observation normalisers (:func:`merge_normalisers`) and
the logged episodes (:func:`gather_episodes`) are merged after every batch; the curricula
count the global frames (``replicas`` in ``trainers.utils.make_env``). Rank 0 alone logs and
checkpoints.

A run is launched by ``torchrun`` (or any launcher that sets torch's ``RANK`` /
``WORLD_SIZE`` / ``LOCAL_RANK`` variables: SLURM through torchrun, a cluster's scheduler) or,
when none did, by the trainer itself with torch's elastic agent (:func:`launch`).
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from tensordict import TensorDictBase
from torch.distributed.launcher.api import LaunchConfig, elastic_launch
from torch.nn.parallel import DistributedDataParallel


@dataclass(frozen=True)
class World:
    """This process's place in the run: rank ``rank`` of ``size``, on ``device``."""

    rank: int = 0
    size: int = 1
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))

    @property
    def main(self) -> bool:
        """Rank 0: the one that logs and checkpoints."""
        return self.rank == 0

    @property
    def parallel(self) -> bool:
        return self.size > 1


def launched() -> bool:
    """Whether a launcher (torchrun, torch's elastic agent) started this process as a rank."""
    return all(name in os.environ for name in ("RANK", "WORLD_SIZE", "LOCAL_RANK"))


def join(world_size: int, device: str) -> World:
    """Join the launcher's process group (gloo on CPU, nccl on CUDA, rank r on
    ``cuda:LOCAL_RANK``); one process without a launcher when ``world_size`` is 1."""
    if world_size == 1 and not launched():
        return World(device=torch.device(device))
    if not launched():
        raise ValueError(f"dist.world_size={world_size}: no launcher set RANK/WORLD_SIZE/"
                         f"LOCAL_RANK (use torchrun, or python -m trainers.ppo alone)")
    size = int(os.environ["WORLD_SIZE"])
    if size != world_size:
        raise ValueError(f"dist.world_size={world_size}, but the launcher started {size} "
                         f"processes")
    rank, local = int(os.environ["RANK"]), int(os.environ["LOCAL_RANK"])
    if torch.device(device).type == "cuda":
        place = torch.device("cuda", local)
        torch.cuda.set_device(place)
        backend = "nccl"
    else:
        place = torch.device(device)
        backend = "gloo"
    if not dist.is_initialized():
        dist.init_process_group(backend, device_id=place if backend == "nccl" else None)
    return World(rank=rank, size=size, device=place)


def leave(world: World) -> None:
    """Leave the process group once every rank is done with it. Every
    ``DistributedDataParallel`` on the group must be gone by then (no reference left): one
    freed after ``destroy_process_group`` takes the group down with it, when the other ranks
    may have exited, and that can hang (seen in about one run of ten of two gloo ranks)."""
    if world.parallel and dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()


def check_cores(world_size: int, device: torch.device) -> int:
    """This process's CPU cores; ValueError where ``world_size`` ranks on the CPU would be
    more than them (ranks sharing a core only run slower, every one of them)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") \
        else os.cpu_count() or 1
    if world_size > cores and device.type == "cpu":
        raise ValueError(f"dist.world_size={world_size} ranks on this machine's {cores} CPU "
                         f"core(s): each rank needs a core of its own (ranks sharing cores "
                         f"only run slower): at most {cores}")
    return cores


def launch(entry: Callable[..., Any], args: Sequence[Any], world_size: int,
           device: torch.device) -> Any:
    """Run ``entry(*args)`` on ``world_size`` local ranks started by torch's elastic agent
    (as ``torchrun --standalone --nproc_per_node=world_size`` would); returns rank 0's
    result. ``entry`` must be importable (ranks start by spawn). On the CPU (``device``) no
    more ranks than cores (:func:`check_cores`). Each rank gets an equal share of the CPU threads
    unless ``OMP_NUM_THREADS`` is set; gloo talks over loopback
    unless ``GLOO_SOCKET_IFNAME`` is set."""
    cores = check_cores(world_size, device)
    print(f"starting {world_size} ranks (torch's elastic agent) on {cores} CPU core(s) ...",
          flush=True)
    os.environ.setdefault("OMP_NUM_THREADS", str(max(1, cores // world_size)))
    os.environ.setdefault("GLOO_SOCKET_IFNAME", "lo")
    config = LaunchConfig(min_nodes=1, max_nodes=1, nproc_per_node=world_size,
                          rdzv_backend="c10d", rdzv_endpoint="localhost:0",
                          run_id=f"torchpark-{uuid.uuid4().hex[:8]}", max_restarts=0)
    return elastic_launch(config, entry)(*args)[0]


def rank_seed(seed: int, rank: int, size: int) -> int:
    """Rank ``rank``'s env seed: ``seed`` itself in a one-process run, else an independent
    stream spawned from it (numpy's SeedSequence), an int in [0, 2**32) as every torchpark
    seed (``torchpark.config.SEED_LIMIT``)."""
    if size == 1:
        return seed
    return int(np.random.SeedSequence(seed, spawn_key=(rank,)).generate_state(1, np.uint32)[0])


def all_reduce_sum_(tensor: torch.Tensor) -> torch.Tensor:
    """Sum ``tensor`` over the ranks, in place (a no-op without a process group)."""
    if dist.is_initialized() and dist.get_world_size() > 1:
        dist.all_reduce(tensor)
    return tensor


def standardise_advantage(advantage: torch.Tensor) -> torch.Tensor:
    """``(a - mean) / std`` with the mean and (unbiased) std over the minibatch of all ranks,
    as ``ClipPPOLoss(normalize_advantage=True)`` computes them over one process's minibatch
    (std clamped at float32's resolution, as torchrl does)."""
    count = torch.tensor(float(advantage.numel()), dtype=torch.float64, device=advantage.device)
    total = advantage.detach().sum(dtype=torch.float64).reshape(1)
    moments = all_reduce_sum_(torch.cat([count.reshape(1), total]))
    mean = moments[1] / moments[0]
    squares = all_reduce_sum_(((advantage.detach().double() - mean) ** 2).sum().reshape(1))
    std = (squares[0] / (moments[0] - 1)).sqrt()
    return (advantage - mean.to(advantage.dtype)) / std.to(advantage.dtype).clamp_min(
        torch.finfo(torch.float).resolution)


def all_gather(obj: Any, world: World) -> list[Any]:
    """``obj`` from every rank, in rank order (``[obj]`` in a one-process run)."""
    if not world.parallel:
        return [obj]
    out: list[Any] = [None] * world.size
    dist.all_gather_object(out, obj)
    return out


def gather_to_main(obj: Any, world: World) -> list[Any] | None:
    """``obj`` from every rank, in rank order, on rank 0 (None on the others)."""
    if not world.parallel:
        return [obj]
    out: list[Any] | None = [None] * world.size if world.main else None
    dist.gather_object(obj, out, dst=0)
    return out


def gather_episodes(batch: TensorDictBase, world: World) -> TensorDictBase | None:
    """The ``next`` entries of the steps that ended an episode, from every rank's batch
    (on CPU, concatenated in rank order); None when no episode ended anywhere."""
    nxt = batch["next"]
    done = nxt["done"][..., 0]
    ended = nxt.select("episode_reward", "step_count", "success", "collision", "truncated",
                       "observation")[done].cpu()
    parts = [part for part in all_gather(ended, world) if part.numel()]
    return torch.cat(parts) if parts else None


# Where VecNormV2's state_dict keeps its statistics: loc / var / count per key.
_NORM_STATE = "_extra_state"


def merge_normalisers(states: Sequence[dict], counted: dict[str, torch.Tensor] | None
                      ) -> dict:
    """One ``VecNormV2`` state from the states of its replicas after a batch (each started
    the batch from the same statistics, whose counts were ``counted``, and forgot at the
    replicated rate, ``trainers.utils.policy_input``): the mean of their moving averages
    (``loc``, ``var``), and the count of every observation any of them saw."""
    first = states[0]
    merged = dict(first[_NORM_STATE])
    for key in merged:
        values = [state[_NORM_STATE][key] for state in states]
        if key.startswith("count"):
            before = counted[key] if counted is not None else torch.zeros_like(values[0])
            merged[key] = before + sum(v - before for v in values)
        else:
            merged[key] = torch.stack([v.to(values[0].device) for v in values]).mean(0)
    return {**first, _NORM_STATE: merged}


def norm_counts(state: dict) -> dict[str, torch.Tensor]:
    """The counts of a ``VecNormV2`` state, to pass to :func:`merge_normalisers` next."""
    return {k: v.clone() for k, v in state[_NORM_STATE].items() if k.startswith("count")}


def check_ranks_agree(modules: list[torch.nn.Module], world: World) -> None:
    """RuntimeError unless every rank holds the same parameters (a step that bypassed the
    gradients' all-reduce would part them): checked at each checkpoint."""
    if not world.parallel:
        return
    mine = torch.cat([p.detach().reshape(-1).cpu() for m in modules for p in m.parameters()])
    if not all(torch.equal(mine, other) for other in all_gather(mine, world)):
        raise RuntimeError("the ranks' networks differ: their gradients were not all-reduced")


def data_parallel(loss_module: torch.nn.Module, world: World, seed: int) -> torch.nn.Module:
    """The loss every rank computes through: ``DistributedDataParallel`` around it with
    several ranks (only DDP's forward all-reduces the gradients), the loss itself with one.
    Each rank then draws from its own stream (the policy's samples, the minibatches)."""
    if not world.parallel:
        return loss_module
    wrapped = DistributedDataParallel(loss_module)
    torch.manual_seed(rank_seed(seed, world.rank, world.size))
    return wrapped
