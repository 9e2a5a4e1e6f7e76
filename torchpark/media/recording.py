"""Videos of policy rollouts, written with imageio (GIF through Pillow, MP4 through ffmpeg)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TypeAlias

import imageio.v3 as iio
import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase
from torchrl.envs.utils import step_mdp

from torchpark.env import ParkingEnv
from torchpark.files import write_file

Policy: TypeAlias = TensorDictModuleBase | Callable[[torch.Tensor], torch.Tensor]
VIDEO_SUFFIXES = (".gif", ".mp4")


def _base(env: EnvBase) -> ParkingEnv:
    base = getattr(env, "base_env", env)
    if not isinstance(base, ParkingEnv):
        raise TypeError(f"env must be a ParkingEnv or a TransformedEnv around one, "
                        f"got {type(base).__name__}")
    return base


def _act(policy: Policy, td: TensorDictBase) -> TensorDictBase:
    if isinstance(policy, TensorDictModuleBase):
        return policy(td)
    td["action"] = policy(td["observation"])
    return td


def rollout_frames(env: EnvBase, policy: Policy, index: int = 0,
                   max_steps: int | None = None) -> list[np.ndarray]:
    """Frames of env ``index``'s next episode, from its reset to its end (or ``max_steps``).

    env: a ParkingEnv, or a TransformedEnv around one (the policy sees what the env emits).
    policy: a torchrl policy (a TensorDictModule writing "action") or any callable from the
    observation (N, obs_dim) to actions (N, 2). Every env of the batch steps; only ``index``
    is drawn, and no row is reset before ``index``'s episode ends (rows that end earlier
    step on past their end, undrawn). Returns (H, W, 3) uint8 frames, the first after the
    reset, the last the step that ended the episode.
    """
    base = _base(env)
    max_steps = base.config.max_steps if max_steps is None else max_steps
    td = env.reset()
    frames = [base.render(index)]
    with torch.no_grad():
        for _ in range(max_steps):
            # step, not step_and_maybe_reset: the last frame shows the ended episode's lot.
            td = env.step(_act(policy, td))
            frames.append(base.render(index))
            if bool(td["next", "done"][index]):
                break
            td = step_mdp(td)
    return frames


def write_video(frames: list[np.ndarray], path: str | Path, fps: float = 10.0) -> Path:
    """Write frames (H, W, 3) uint8 to ``path`` (.gif or .mp4) at ``fps``, whole or not at
    all (``torchpark.files``); returns the path.

    MP4 frames are padded (white) to multiples of 16 pixels, as H.264 players expect.
    """
    path = Path(path)
    if path.suffix not in VIDEO_SUFFIXES:
        raise ValueError(f"path must end in one of {VIDEO_SUFFIXES}, got {str(path)!r}")
    if not frames:
        raise ValueError("frames must hold at least one frame, got none")
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps!r}")
    stack = np.stack(frames)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gif":
        return write_file(path, lambda tmp: iio.imwrite(tmp, stack, duration=1000.0 / fps,
                                                        loop=0))
    h, w = stack.shape[1:3]
    pad = ((0, 0), (0, -h % 16), (0, -w % 16), (0, 0))
    padded = np.pad(stack, pad, constant_values=255)
    return write_file(path, lambda tmp: iio.imwrite(tmp, padded, fps=fps))


def record_video(env: EnvBase, policy: Policy, path: str | Path, index: int = 0,
                 max_steps: int | None = None, fps: float = 10.0) -> Path:
    """One episode of ``policy`` in env ``index`` to a GIF or MP4 (see :func:`rollout_frames`)."""
    return write_video(rollout_frames(env, policy, index, max_steps), path, fps)
