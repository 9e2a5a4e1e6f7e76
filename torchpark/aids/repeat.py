"""Held actions (action repeat): one env step holds the action for up to k steps of dt,
stopping at the one that ends the episode, and returns the sum of their rewards. A wrapper
around any step function, as Brax's ``EpisodeWrapper`` wraps its pure step. Only the held
steps' last observation is read, so the steps of dt skip the LIDAR (``scan=False``) and the
observation is taken once, of the state they end in: the same numbers, a fifth of the LIDAR
work at ``fast``'s 5 steps."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from torchpark.sim.records import replace
from torchpark.sim.state import StepResult
from torchpark.sim.step import mux_rows

StepFn = Callable[..., tuple[tuple, StepResult, Tensor]]


def merge_steps(state: tuple, out: StepResult, new_state: tuple, new_out: StepResult
                ) -> tuple[tuple, StepResult]:
    """Append one more step of dt (``new_*``, taken from ``state``) to a held action's steps
    so far: rows already done keep their state and outputs; the others take the new ones,
    with the rewards summed and the lowest cost C kept (where a looser success test would
    have ended the held action)."""
    live = ~out.done[:, 0]
    merged = mux_rows(live, new_out, out)
    return mux_rows(live, new_state, state), replace(
        merged, reward=out.reward + torch.where(live[:, None], new_out.reward, 0.0),
        cost=torch.minimum(out.cost, merged.cost))


def hold(step: StepFn, repeat: int, observe: Callable[[tuple], Tensor]) -> StepFn:
    """``step(state, action, scan) -> (state, StepResult, finite)`` with each action held for
    ``repeat`` steps of dt, merged by :func:`merge_steps` (one function: one graph when
    compiled): its steps run with ``scan=False``, and the observation is ``observe(state)``
    of the state they end in (each row's: where its episode ended, or the last step's).
    Returns ``step`` itself when ``repeat`` is 1."""
    if repeat == 1:
        return step

    def held(state: tuple, action: Tensor) -> tuple[tuple, StepResult, Tensor]:
        state, out, finite = step(state, action, scan=False)
        for _ in range(repeat - 1):
            state, out = merge_steps(state, out, *step(state, action, scan=False)[:2])
        return state, replace(out, observation=observe(state)), finite

    return held
