"""The reset of the rows a step ends, inside the step's graph: no data-dependent shape and no
host read.

New episodes are drawn ahead in blocks of N (one batched draw each) and held in a ring of R
blocks (R N rows). Two device counters say where the hand-out stands: ``block``, the block
the rows are handed out from (an absolute count: its rows are ring rows
``(block mod R) N ..``), and ``used``, how many of its rows are handed out. The k-th row that
ends (in index order) takes the block's next free row; when the block does not hold enough
for every ended row, the rest of it is skipped and they come from the start of the next
block. That is the order ``ParkingEnv``'s host path hands episodes out in (it reads the
count), so both give the same rows the same episodes.

A hand-out moves ``block`` by at most one, so with blocks ``block .. block + R - 1`` drawn the
host can let R - 1 hand-outs run before it reads ``block`` back and draws the blocks spent:
one read (on CUDA a synchronisation) every R - 1 steps instead of one per step.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch
from torch import Tensor

from torchpark.sim.state import StepResult
from torchpark.sim.step import mux_rows, take_rows

# What a reset reports for every row, all False: (N, 1) bool each.
END_FLAGS = ("success", "collision", "done", "terminated", "truncated")


class Counters(NamedTuple):
    """Where the hand-out stands, () int64 tensors on the env's device: ``block``, the block
    rows are handed out from (absolute, never wrapped), ``used``, its rows handed out (0..N)."""

    block: Tensor
    used: Tensor


def hand_out(done: Tensor, counters: Counters, blocks: int) -> tuple[Tensor, Counters]:
    """Which ring row each ended row takes: ``done`` (N,) bool, a ring of ``blocks`` blocks
    of N rows. Returns the flat ring rows (N,) int64 (meaningful where ``done``; the others
    hold a valid row, to be muxed away) and the counters after the hand-out."""
    n = done.shape[0]
    rank = done.cumsum(0) - 1  # the k-th ended row (k from 0), in index order
    count = rank[-1] + 1
    switched = count > n - counters.used  # the block's rest is skipped: the next one
    block = counters.block + switched.long()
    start = torch.where(switched, 0, counters.used)
    index = (block % blocks) * n + (start + rank).clamp(0, n - 1)
    return index, Counters(block, start + count)


def reset_rows(done: Tensor, rows: tuple, ring: tuple, counters: Counters
               ) -> tuple[tuple, Counters]:
    """The rows where ``done`` (N,) bool replaced by the next episodes of the ``ring`` (the
    structure of ``rows``: tuples and NamedTuples of [R N, ...] tensors beside [N, ...]), as
    :func:`hand_out` assigns them; the other rows as they are. Returns the rows and the
    counters after."""
    blocks = ring[-1].shape[0] // done.shape[0]
    index, counters = hand_out(done, counters, blocks)
    return mux_rows(done, take_rows(ring, index), rows), counters


def guarded_step(step: Callable, state: tuple, action: Tensor, bad_action: Tensor) -> tuple:
    """``step(state, action) -> (state, StepResult, finite)`` with no host read for the action
    check: a row whose action (N, 2) holds a non-finite value takes the action (0, 0) instead
    (it stands still) and sets ``bad_action`` () bool, which the host reads with the
    counters. Returns (state, StepResult, bad_action)."""
    finite = action.isfinite().all(dim=-1, keepdim=True)
    state, out, _ = step(state, torch.where(finite, action, 0.0))
    return state, out, bad_action | ~finite.all()


def step_and_reset(step: Callable, fields: Callable, state: tuple, action: Tensor,
                   ring: tuple, counters: Counters, bad_action: Tensor) -> tuple:
    """One step of every row (:func:`guarded_step`) and the reset of the rows it ends, as one
    function (one graph when compiled). ``fields(state, observation, cost) -> dict``: the
    env's outputs that are read from its state.

    Returns (the rows after the reset: (state, observation (N, D), cost (N,)); the step's
    outputs, ``StepResult`` fields beside ``fields`` of the state the step reached: what
    torchrl files under "next", an ended row's last observation among them; what a reset
    returns for the rows after it: copies of their ``fields`` (the env keeps the rows) and
    the end flags, all False; the counters; ``bad_action``).
    """
    state, out, bad_action = guarded_step(step, state, action, bad_action)
    done = out.done[:, 0]
    stepped = (state, out.observation, out.cost[:, 0])
    rows, counters = reset_rows(done, stepped, ring, counters)
    reached = {**{k: v for k, v in zip(StepResult._fields, out, strict=True)
                  if k not in ("observation", "cost")}, **fields(*stepped)}
    after = {**{k: v.clone() for k, v in fields(*rows).items()},
             **{k: torch.zeros_like(out.done) for k in END_FLAGS}}
    return rows, reached, after, counters, bad_action
