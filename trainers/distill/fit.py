"""The distiller's fit: minibatch regression of the student on the teacher's labels, over the
whole aggregate (DAgger's refit) or, with ``dagger.replay``, over an iteration's new states
and a bounded sample of the earlier ones (:func:`passes`)."""

from __future__ import annotations

import torch
from tensordict import TensorDict

from trainers.distill.config import DaggerConfig
from trainers.distill.labels import STUDENT_INPUT
from trainers.heads import BinnedGearHead, imitation_error
from trainers.utils import NORMALISED


def plan(cfg: DaggerConfig, iteration: int) -> tuple[int, float]:
    """The passes and the replay ratio of ``iteration``'s fit (counted from 0):
    ``cfg.epochs`` after the first, ``cfg.dagger_epochs`` after each later one, replayed by
    ``cfg.replay``; the last of ``cfg.iterations``, where ``cfg.final_epochs`` > 0, that many
    passes over the whole aggregate (replay 0)."""
    if iteration == cfg.iterations - 1 and cfg.final_epochs:
        return cfg.final_epochs, 0.0
    return (cfg.epochs if iteration == 0 else cfg.dagger_epochs), cfg.replay


def passes(total: int, new: int, epochs: int, replay: float, generator: torch.Generator,
           kept: tuple[int, int] = (0, 0)) -> tuple[list[torch.Tensor], torch.Tensor]:
    """The order of each of ``epochs`` passes over an aggregate of ``total`` states whose last
    ``new`` an iteration has just labelled, and each state's weight relative to its own
    (``total``,). ``replay`` 0 (or no earlier state): every state, a fresh permutation per
    pass, each weighing its own (the full refit, whose work grows with the aggregate).
    ``replay`` r > 0: per pass the new states, the earlier ones in ``kept`` (start, stop: the
    final-approach states, a fixed set the fit holds in every pass) and a fresh uniform draw
    of ``min(others, round(r * new))`` of the other earlier ones (without replacement),
    shuffled together; those weigh ``others / drawn`` times their own, so that each pass's
    loss is the whole aggregate's in expectation, and a pass's work is bounded by
    ``(1 + r) * new`` states and the kept ones, whatever the iteration."""
    earlier = total - new
    scale = torch.ones(total)
    if replay == 0 or earlier == 0:
        return [torch.randperm(total, generator=generator) for _ in range(epochs)], scale
    start, stop = kept
    held = torch.arange(start, stop)
    others = torch.cat((torch.arange(start), torch.arange(stop, earlier)))
    drawn = min(others.shape[0], round(replay * new))
    if drawn:
        scale[others] = others.shape[0] / drawn
    order = []
    for _ in range(epochs):
        picked = torch.cat((others[torch.randperm(others.shape[0], generator=generator)[:drawn]],
                            held, torch.arange(earlier, total)))
        order.append(picked[torch.randperm(picked.shape[0], generator=generator)])
    return order, scale


def fit(actor, norm, inputs: torch.Tensor, labels: torch.Tensor, weights: torch.Tensor,
        order: list[torch.Tensor], cfg: DaggerConfig, optim: torch.optim.Optimizer) -> float:
    """Passes of minibatch regression of the student's deterministic action (tanh of its loc)
    on the labels (N, 2) (:func:`imitation_error`, or the binned steering's own,
    :meth:`trainers.heads.BinnedGearHead.imitation_error`; weighted per state by ``weights``
    (N,)), one per index tensor of ``order`` (:func:`passes`), in minibatches of
    ``cfg.batch_size``, the learning rate from ``cfg.lr`` (to 0 along a cosine over the fit
    with ``cfg.lr_decay``); returns the last pass's mean loss."""
    net = actor.module[0]
    body = net.module[0]  # the policy's network before its scale head
    for group in optim.param_groups:
        group["lr"] = cfg.lr
    batches = sum(-(-indices.shape[0] // cfg.batch_size) for indices in order)
    schedule = (torch.optim.lr_scheduler.CosineAnnealingLR(optim, batches) if cfg.lr_decay
                else None)
    losses = []
    for indices in order:
        losses = []
        for index in indices.split(cfg.batch_size):
            td = norm(TensorDict({STUDENT_INPUT: inputs[index]}, [index.shape[0]]))
            if isinstance(body, BinnedGearHead):
                error = body.imitation_error(td[NORMALISED], labels[index])
            else:
                error = imitation_error(torch.tanh(net(td)["loc"]), labels[index])
            loss = (weights[index] * error).mean()
            optim.zero_grad()
            loss.backward()
            optim.step()
            if schedule is not None:
                schedule.step()
            losses.append(loss.detach())
    return torch.stack(losses).mean().item()
