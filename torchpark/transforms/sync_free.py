"""A ``TransformedEnv`` around a ``ParkingEnv(reset_in_step=True)`` whose
``step_and_maybe_reset`` reads nothing back to the host (on CUDA: no synchronisation per step),
and the torchrl transforms the trainer uses, without their per-step reads.

torchrl's generic ``step_and_maybe_reset`` reads ``done.any()`` to decide whether to reset at
all, then checks the reset's done flags and reads ``done.all()`` to choose its merge;
``VecNormV2`` reads its ``initialized`` flag and ``RewardScaling`` its ``standard_normal``
flag (both tensors) at every step. Here the base env resets its ended rows inside its step
(``torchpark.sim.ring``), the transforms' reset runs at every step with the done rows as its
mask, and the merge is a ``where``: the same tensordicts as torchrl's path, bit for bit
(``tests/test_sync_free.py``), with the normaliser's statistics held where no row ended, as
torchrl's path, which then calls no reset, holds them.

torchrl's native-autoreset path (``_torchrl_native_autoreset``) would also skip the read, but
it overwrites an ended row's last observation with NaN, which GAE needs to bootstrap a
truncated episode.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import RewardScaling, TransformedEnv, VecNormV2

from torchpark._compat import (
    post_step_mdp_hooks,
    reset_env_preprocess,
    step_mdp,
    transform_reset,
)


class SyncFreeEnv(TransformedEnv):
    """``TransformedEnv`` whose ``step_and_maybe_reset`` (the collectors' and rollouts' path)
    reads nothing back when its base env is a ``ParkingEnv(reset_in_step=True)``; with any
    other base env it is torchrl's generic path. The one read left is the base env's own:
    its ring counters, once every ``blocks_ahead`` steps."""

    def _step_and_maybe_reset(self, tensordict: TensorDictBase
                              ) -> tuple[TensorDictBase, TensorDictBase]:
        base = self.base_env
        if not getattr(base, "reset_in_step", False):
            return super()._step_and_maybe_reset(tensordict)
        if tensordict.device != self.device:
            tensordict = tensordict.to(self.device)
        tensordict, after = base.step_resetting(self.step, tensordict)
        hooks = post_step_mdp_hooks(self)
        assert hooks is not None  # a TransformedEnv's, which torchrl always sets
        tensordict, tensordict_ = hooks(tensordict, step_mdp(self, tensordict))
        done = tensordict.get(("next", "done")).reshape(self.batch_size)
        # torchrl's reset(select_reset_only=True) of the done rows, every step: the reset
        # request holds the mask alone; the base env's part of the reset is ``after``.
        request = TensorDict({"_reset": done.unsqueeze(-1).clone()}, batch_size=self.batch_size,
                             device=self.device)
        fresh = transform_reset(self.transform, reset_env_preprocess(self.transform, request),
                                after)
        return tensordict, merge_reset(tensordict_, fresh, done)


def merge_reset(tensordict_: TensorDictBase, fresh: TensorDictBase, done: torch.Tensor
                ) -> TensorDictBase:
    """torchrl's merge of a reset into the next step's root (``_update_during_reset``)
    without its read of ``done.all()``: ``fresh``'s keys taken in the ``done`` (batch,) rows,
    the others of ``tensordict_`` zeroed there unless every row is done (torchrl pads a
    partial reset only). Updates and returns ``tensordict_``."""
    shared = tensordict_.select(*fresh.keys(True, True), strict=False)
    others = tensordict_.exclude(*fresh.keys(True, True))
    tensordict_.update(fresh.where(done, shared, pad=0))
    if not others.is_empty():
        tensordict_.update(others.masked_fill(done & ~done.all(), 0))
    return tensordict_


class SyncFreeVecNorm(VecNormV2):
    """``VecNormV2`` (stateful) that reads nothing back per step: the statistics exist from
    the spec's initialisation on, so the per-step read of its ``initialized`` flag is skipped
    (as torchrl skips it when compiling); and a reset whose mask has no row set (which
    :class:`SyncFreeEnv` makes at every step) leaves the statistics as they were, where
    torchrl's generic path would not have reset at all."""

    def _maybe_stateful_init(self, data: TensorDictBase) -> None:
        if self._loc is None:  # before the first data: torchrl's initialisation
            super()._maybe_stateful_init(data)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
               ) -> TensorDictBase:
        reset = tensordict.get("_reset", None)
        if reset is None or not self.stateful or self._loc is None:
            return super()._reset(tensordict, tensordict_reset)
        before = [leaf.clone() for leaf in self._statistics()]
        out = super()._reset(tensordict, tensordict_reset)
        hold = ~reset.any()
        for now, was in zip(self._statistics(), before, strict=True):
            now.copy_(torch.where(hold, was, now))
        return out

    def _statistics(self) -> list[torch.Tensor]:
        """The tensors of the running statistics (updated in place by torchrl)."""
        return [leaf for stat in (self._loc, self._var, self._count)
                for leaf in (stat.values(True, True) if isinstance(stat, TensorDictBase)
                             else [stat])]


class SyncFreeRewardScaling(RewardScaling):
    """``RewardScaling`` with ``standard_normal`` fixed at construction: torchrl's reads the
    flag, a tensor, at every step."""

    def __init__(self, loc: float, scale: float, in_keys: list | None = None,
                 out_keys: list | None = None, standard_normal: bool = False) -> None:
        super().__init__(loc, scale, in_keys=in_keys, out_keys=out_keys,
                         standard_normal=standard_normal)
        self._standard_normal = bool(standard_normal)

    def _apply_transform(self, reward: torch.Tensor) -> torch.Tensor:
        if self._standard_normal:
            return (reward - self.loc) / self.scale
        return reward * self.scale + self.loc
