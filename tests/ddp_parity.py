"""One rank of tests/test_distributed.py's parity check, started by torchrun:

    python -m torch.distributed.run --standalone --nproc_per_node=2 -m tests.ddp_parity DIR

Takes the PPO steps of :func:`steps` on its share of each minibatch of ``DIR/batch.pt``,
from the networks in ``DIR/init.pt``, in each of two modes, and writes its parameters to
``DIR/MODE_rankR.pt``. MODE ``ddp``: through ``DistributedDataParallel`` (the trainer's
path); ``nosync``: the same steps without it (the control: gradients never all-reduced).
Both in one launch: starting the ranks is most of the time.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from tensordict import TensorDict
from torch.nn.parallel import DistributedDataParallel
from torchrl.objectives import ClipPPOLoss

from trainers.config import load_config
from trainers.distributed import join, leave
from trainers.ppo import ppo_step
from trainers.utils import build_models

BATCH, MINIBATCH, EPOCHS = 1024, 256, 2


def make_loss() -> ClipPPOLoss:
    """The smoke preset's networks and loss (as trainers.ppo builds them)."""
    cfg = load_config("smoke")
    actor, critic = build_models(cfg)
    return ClipPPOLoss(actor, critic, clip_epsilon=0.2, entropy_bonus=False,
                       critic_coeff=0.5, loss_critic_type="l2",
                       normalize_advantage=False)


def minibatches(rank: int, size: int) -> list[torch.Tensor]:
    """Rank ``rank``'s share (a contiguous slice) of each global minibatch, fixed."""
    generator = torch.Generator().manual_seed(0)
    out = []
    for _ in range(EPOCHS):
        for index in torch.randperm(BATCH, generator=generator).split(MINIBATCH):
            share = MINIBATCH // size
            out.append(index[rank * share:(rank + 1) * share])
    return out


def steps(loss: ClipPPOLoss, batch: TensorDict, rank: int, size: int,
          loss_fn: torch.nn.Module | None = None) -> torch.Tensor:
    """The PPO steps on this rank's shares; returns the parameters after them, flat."""
    optim = torch.optim.Adam(loss.parameters(), lr=3e-4)
    for index in minibatches(rank, size):
        ppo_step(loss_fn if loss_fn is not None else loss, optim, batch[index], 0.5)
    return torch.cat([p.detach().reshape(-1) for p in loss.parameters()])


def load(directory: Path, loss: ClipPPOLoss) -> TensorDict:
    loss.load_state_dict(torch.load(directory / "init.pt", weights_only=True))
    return TensorDict.from_dict(torch.load(directory / "batch.pt", weights_only=True),
                                batch_size=[BATCH])


def main() -> None:
    directory = Path(sys.argv[1])
    world = join(2, "cpu")
    for mode in ("ddp", "nosync"):
        loss = make_loss()
        batch = load(directory, loss)
        # The control differs in one thing: no DDP, so no gradient is all-reduced (the
        # advantages are still standardised over both ranks).
        loss_fn = DistributedDataParallel(loss) if mode == "ddp" else loss
        params = steps(loss, batch, world.rank, world.size, loss_fn)
        torch.save(params, directory / f"{mode}_rank{world.rank}.pt")
        del loss_fn  # DDP goes before its process group (trainers.distributed.leave)
    leave(world)


if __name__ == "__main__":
    main()
