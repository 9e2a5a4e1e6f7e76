"""A training aid: the success test's threshold, loose at first and tightened as training
succeeds, as a TorchRL transform (the paper's test is fixed at 4e-4)."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from tensordict import TensorDictBase

from torchpark.config import is_number
from torchpark.curriculum import FrameCountingTransform, frame_count


class SuccessCurriculum(FrameCountingTransform):
    """Sets the base ``ParkingEnv``'s success threshold, from a loose ``start`` (so that the
    success bonus is seen early in training) down to ``final`` as training succeeds.

    Every ``window`` frames, if at least ``target`` of the episodes that ended in the window
    succeeded, the threshold is multiplied by ``factor`` (and kept >= ``final``); else it
    stays. The decision is a ``torch.where`` on device and the frame count a Python int: no
    step reads a device tensor. The threshold and the window's counts are buffers, so
    ``env.state_dict()`` resumes them.

    Args:
        start: the threshold on C to begin with, > 0.
        final: the threshold to end at, in (0, start] (the paper's 4e-4 by default).
        factor: the multiplier of one tightening, in (0, 1).
        target: the success rate in (0, 1] of a window that earns a tightening.
        window: frames (steps of dt summed over the batch) per decision, >= 1.
        replicas: copies of this env stepping in lockstep (``FrameCountingTransform``).
        reduce: with replicas, sums a tensor over them in place (e.g.
            ``torch.distributed.all_reduce``), so that each window's decision is taken on the
            episodes of all of them and every copy holds the same threshold. Called once per
            window, at the same step on every copy.
    """

    def __init__(self, start: float, final: float = 4e-4, factor: float = 0.5,
                 target: float = 0.5, window: int = 163_840, replicas: int = 1,
                 reduce: Callable[[torch.Tensor], object] | None = None) -> None:
        super().__init__(replicas)
        if reduce is not None and not callable(reduce):
            raise ValueError(f"reduce must be None or a callable, got {reduce!r}")
        self.reduce = reduce
        for name, value in (("start", start), ("final", final), ("factor", factor),
                            ("target", target)):
            if not is_number(value) or not math.isfinite(value):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        for name, value, ok, bounds in (("start", start, start > 0, "> 0"),
                                        ("final", final, 0 < final <= start, "in (0, start]"),
                                        ("factor", factor, 0 < factor < 1, "in (0, 1)"),
                                        ("target", target, 0 < target <= 1, "in (0, 1]")):
            if not ok:
                raise ValueError(f"{name} must be {bounds}, got {value!r}")
        self.final, self.factor, self.target = final, factor, target
        self.window = frame_count("window", window)
        self.register_buffer("threshold", torch.tensor(float(start)))
        self.register_buffer("ended", torch.zeros(()))
        self.register_buffer("succeeded", torch.zeros(()))
        self._stale = True  # the env does not hold this threshold yet

    @property
    def success_threshold(self) -> float:
        """The current threshold (reads the buffer: a host sync on CUDA)."""
        return float(self.threshold)

    def _push(self) -> None:
        # Only a new threshold is pushed (before the first reset, after a window's decision
        # or a load): with near-goal starts, the env discards its episodes drawn ahead on
        # each new threshold.
        container = self.container
        if container is not None and self._stale:
            container.base_env.set_success_threshold(self.threshold)
            self._stale = False

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        self._stale = True
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
              ) -> TensorDictBase:
        done = next_tensordict.get("done")
        self.ended += done.sum()
        self.succeeded += (done & next_tensordict.get("success")).sum()
        before = self._count(next_tensordict)
        if self._frames // self.window > before // self.window:
            if self.reduce is not None:
                counts = torch.stack([self.ended, self.succeeded])
                self.reduce(counts)
                self.ended.copy_(counts[0])
                self.succeeded.copy_(counts[1])
            rate = self.succeeded / self.ended.clamp_min(1.0)
            tighter = (self.threshold * self.factor).clamp_min(self.final)
            self.threshold.copy_(torch.where(rate >= self.target, tighter, self.threshold))
            self.ended.zero_()
            self.succeeded.zero_()
            self._stale = True
            self._push()
        return next_tensordict

    def extra_repr(self) -> str:
        return (f"threshold={self.success_threshold:.3g}, final={self.final}, "
                f"factor={self.factor}, target={self.target}, window={self.window}, "
                f"frames_seen={self._frames}")
