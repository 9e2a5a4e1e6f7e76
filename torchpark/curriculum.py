"""The paper's fixed-schedule curriculum as a TorchRL transform: occupancy rises every
``frames_per_level`` frames (env steps summed over the batch, each counted as
``action_repeat`` frames: frames are steps of the vehicle's dt) and stays at the last level."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.envs.transforms import Transform

from torchpark.config import check_occupancy

PAPER_LEVELS = (0.0, 0.2, 0.4, 0.6, 0.8, 0.9)


def level_at(frames: int, frames_per_level: int, count: int) -> int:
    """Index of the level reached after ``frames`` frames when each of ``count`` levels lasts
    ``frames_per_level`` frames (the last one holds from then on)."""
    return min(frames // frames_per_level, count - 1)


def frame_count(name: str, value: int) -> int:
    """``value`` if it is an int >= 1 (a number of frames), else a ValueError naming it."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be an int >= 1, got {value!r}")
    return value


class FrameCountingTransform(Transform):
    """A transform that counts frames (env steps summed over the batch, ``action_repeat``
    frames each) in a buffer mirrored by a Python int, so that no step reads a device tensor
    and ``state_dict``/``load_state_dict`` carry and resume the count, and that sets its
    value in the base env (``_push``) before each step and reset and after a load.

    ``replicas``: how many envs of this batch size step in lockstep with this one in the run
    (data-parallel ranks x collector workers, each with its own copy of the transform); each
    step counts their frames too, so every copy follows the run's global frame count.
    """

    def __init__(self, replicas: int = 1) -> None:
        super().__init__()
        self.replicas = frame_count("replicas", replicas)
        self.register_buffer("frames", torch.zeros((), dtype=torch.int64))
        self._frames = 0

    @property
    def frames_seen(self) -> int:
        """Frames stepped through this transform."""
        return self._frames

    def _step_frames(self, tensordict: TensorDictBase) -> int:
        """The frames one step of this batch counts."""
        container = self.container
        repeat = container.base_env.action_repeat if container is not None else 1
        return tensordict.numel() * repeat * self.replicas

    def _count(self, next_tensordict: TensorDictBase) -> None:
        """Add a step's frames."""
        self._frames += self._step_frames(next_tensordict)
        self.frames.fill_(self._frames)  # an async fill from a host int: no sync

    def _push(self, frames: int) -> None:
        """Set the base env's value for ``frames`` frames stepped."""
        raise NotImplementedError

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        # Before each step, the value its frames reach: the rows a ParkingEnv with
        # reset_in_step resets inside that step then draw the lots the host path's reset
        # after the step draws (both paths, the same rollout).
        self._push(self._frames + self._step_frames(tensordict))
        return super()._inv_call(tensordict)

    def _reset_env_preprocess(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._push(self._frames)  # before the base env draws its new lots
        return super()._reset_env_preprocess(tensordict)

    def _load_from_state_dict(self, state_dict: dict, prefix: str, *args: Any, **kwargs: Any
                              ) -> None:
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self._frames = int(self.frames)
        if "_container" in self.__dict__:
            self._push(self._frames)


class OccupancyCurriculum(FrameCountingTransform):
    """Sets the base ``ParkingEnv``'s occupancy from the number of frames stepped so far.

    Level ``k`` (phase ``k + 1``) holds from ``k * frames_per_level`` frames on; the new level
    applies to lots drawn at later resets. The frame count is a buffer, so ``env.state_dict()``
    and ``collector.state_dict()`` carry it and ``load_state_dict`` resumes the schedule. The
    count is also mirrored in a Python int, so no step reads a device tensor (no host sync).

    Build a fresh transform (or none) for an evaluation env: ``clone()`` shares the buffer.
    With ``replicas`` copies of the env in lockstep (see :class:`FrameCountingTransform`)
    the schedule follows the frames of all of them.
    """

    def __init__(self, levels: Sequence[float] = PAPER_LEVELS,
                 frames_per_level: int = 2_000_000, replicas: int = 1) -> None:
        super().__init__(replicas)
        levels = tuple(levels)
        if not levels:
            raise ValueError("levels must hold at least one occupancy, got an empty sequence")
        self.levels = tuple(check_occupancy(v, f"levels[{i}]") for i, v in enumerate(levels))
        self.frames_per_level = frame_count("frames_per_level", frames_per_level)

    @property
    def level(self) -> int:
        """Index into ``levels`` of the current level."""
        return self._level_at(self._frames)

    def _level_at(self, frames: int) -> int:
        return level_at(frames, self.frames_per_level, len(self.levels))

    @property
    def phase(self) -> int:
        """The paper's phase number, 1-based."""
        return self.level + 1

    @property
    def occupancy(self) -> float:
        """The occupancy of the current level."""
        return self.levels[self.level]

    def _push(self, frames: int) -> None:
        container = self.container
        if container is not None:
            container.base_env.occupancy = self.levels[self._level_at(frames)]

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
              ) -> TensorDictBase:
        self._count(next_tensordict)  # its level was set before the step (_inv_call)
        return next_tensordict

    def extra_repr(self) -> str:
        return (f"levels={self.levels}, frames_per_level={self.frames_per_level}, "
                f"frames_seen={self._frames}, phase={self.phase}")
