"""Where a compiled PPO update parts from the eager one (issue 88, "the version pins tried" in
research/experiments.md): the gradients of one backward of the trainer's loss on the saturated
draws of ``tests/test_trainer.py``, eager against ``torch.compile``, with and without the
gradient clipping, and Adam alone on given gradients.

    PYTHONPATH=. python research/compiled_update_probe.py

On torch 2.13.0 every difference is below 1e-6; on 2.14.1 and 2.15.0 the clipped gradients
part by 1.1e-4 (6.5e-4 unclipped).
"""

from __future__ import annotations

import torch
from torchrl.objectives import ClipPPOLoss

from tests.test_trainer import saturated_draws
from trainers.ppo import recompute_log_prob_, standardise_advantage


def backward(loss_fn: ClipPPOLoss, sample, clip: bool) -> None:
    """The first half of ``trainers.ppo.ppo_step``: the loss, its backward, the clipping."""
    sample.set("advantage", standardise_advantage(sample["advantage"]))
    losses = loss_fn(sample)
    total = losses["loss_objective"] + losses["loss_critic"]
    if "loss_entropy" in losses.keys():
        total = total + losses["loss_entropy"]
    total.backward()
    if clip:
        torch.nn.utils.clip_grad_norm_(list(loss_fn.parameters()), 0.5)


def gradients(compiled: bool, clip: bool) -> torch.Tensor:
    torch.manual_seed(0)
    actor, critic, td = saturated_draws(0.0)
    recompute_log_prob_(actor, td, "action_log_prob")
    loss = ClipPPOLoss(actor, critic, normalize_advantage=False)
    (torch.compile(backward) if compiled else backward)(loss, td.split(64)[0].clone(), clip)
    return torch.cat([p.grad.flatten() for p in loss.parameters() if p.grad is not None])


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
