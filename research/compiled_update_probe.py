"""Where a compiled PPO update parts from the eager one (issue 88, "the version pins tried" in
research/experiments.md): the gradients of one backward of the trainer's loss on the saturated
draws of ``tests/test_trainer.py``, eager against ``torch.compile``, with and without the
gradient clipping, and Adam alone on given gradients.

    PYTHONPATH=. python research/compiled_update_probe.py

On torch 2.13.0 every difference is below 1e-6; on 2.14.1 and 2.15.0 the clipped gradients
part by 1.1e-4 (6.5e-4 unclipped).
"""

from __future__ import annotations

import math
from functools import partial

import torch
from torchrl.objectives import ClipPPOLoss

from tests.test_trainer import saturated_draws
from trainers.ppo import ppo_step, recompute_log_prob_


def gradients(compiled: bool, clip: bool) -> torch.Tensor:
    """The (clipped) gradient of one ``trainers.ppo.ppo_step``, read as what plain SGD at
    learning rate 1 moves the parameters by."""
    torch.manual_seed(0)
    actor, critic, td = saturated_draws(0.0)
    recompute_log_prob_(actor, td, "action_log_prob")
    loss = ClipPPOLoss(actor, critic, normalize_advantage=False)
    before = torch.cat([p.detach().flatten() for p in loss.parameters()])
    step = partial(ppo_step, loss, torch.optim.SGD(loss.parameters(), lr=1.0),
                   max_grad_norm=0.5 if clip else math.inf)
    (torch.compile(step) if compiled else step)(td.split(64)[0].clone())
    return before - torch.cat([p.detach().flatten() for p in loss.parameters()])


def adam(compiled: bool) -> torch.Tensor:
    torch.manual_seed(0)
    p = torch.nn.Parameter(torch.randn(1000))
    optim = torch.optim.Adam([p], lr=1e-2)
    step = torch.compile(optim.step) if compiled else optim.step
    for k in range(3):
        p.grad = torch.randn(1000, generator=torch.Generator().manual_seed(k))
        step()
    return p.detach().clone()


if __name__ == "__main__":
    print(f"torch {torch.__version__}")
    for clip in (False, True):
        eager, compiled = gradients(False, clip), gradients(True, clip)
        print(f"clip={clip}: max |compiled - eager| gradient {(compiled - eager).abs().max():.2e}"
              f" (max |gradient| {eager.abs().max():.2f})")
    print(f"Adam alone: max |compiled - eager| {(adam(True) - adam(False)).abs().max():.2e}")
