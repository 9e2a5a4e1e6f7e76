"""Policy features computed from the paper's observation: the goal in the vehicle's frame.

The paper's observation gives the goal offset in the world frame; a policy then has to learn a
rotation by the heading before it can steer. These features hand it the rotated offset, and a
log-like scale (``asinh(x / precision)``) that stays informative down to the millimetres the
success test asks for, where a world-frame offset normalised by metres is flat.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform

from torchpark.sim.observation import NAV_DIM

GOAL_FEATURES = 7  # ex, ey, cos and sin of the heading error, three asinh scales


def goal_in_vehicle_frame(observation: Tensor, precision: float = 0.01) -> Tensor:
    """[..., NAV_DIM + n_rays] observation -> [..., GOAL_FEATURES] float features of the goal
    seen from the car.

    Features: (ex, ey) goal minus rear axle in the vehicle frame (m, x forward, y left);
    cos, sin of the heading error wrap(alpha - psi); asinh(ex / precision),
    asinh(ey / precision), asinh(heading error / precision) with ``precision`` in m (and rad).
    """
    if observation.shape[-1] < NAV_DIM:
        raise ValueError(f"observation must have >= {NAV_DIM} features, got shape "
                         f"{tuple(observation.shape)}")
    dx, dy, cos_psi, sin_psi, _, cos_alpha, sin_alpha = observation[..., :NAV_DIM].unbind(-1)
    ex = cos_psi * dx + sin_psi * dy
    ey = cos_psi * dy - sin_psi * dx
    cos_err = cos_alpha * cos_psi + sin_alpha * sin_psi
    sin_err = sin_alpha * cos_psi - cos_alpha * sin_psi
    err = torch.atan2(sin_err, cos_err)
    scale = 1.0 / precision
    return torch.stack([ex, ey, cos_err, sin_err, torch.asinh(ex * scale),
                        torch.asinh(ey * scale), torch.asinh(err * scale)], dim=-1)


class GoalFrameFeatures(Transform):
    """Writes ``out_key`` = cat(observation, :func:`goal_in_vehicle_frame`) and keeps
    ``in_key`` (the paper's 23-dim observation) as it is.

    Args:
        in_key: the paper's observation key.
        out_key: where the [..., obs_dim + GOAL_FEATURES] policy input goes.
        precision: the length (m) and angle (rad) below which the asinh features turn linear.
    """

    def __init__(self, in_key: str = "observation", out_key: str = "observation_policy",
                 precision: float = 0.01) -> None:
        if not precision > 0:
            raise ValueError(f"precision must be > 0 (m), got {precision!r}")
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.precision = precision

    def _apply_transform(self, observation: Tensor) -> Tensor:
        features = goal_in_vehicle_frame(observation, self.precision)
        return torch.cat([observation, features], dim=-1)

    def _reset(self, tensordict, tensordict_reset):
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        source = observation_spec[self.in_keys[0]]
        shape = (*source.shape[:-1], source.shape[-1] + GOAL_FEATURES)
        observation_spec[self.out_keys[0]] = Unbounded(shape=shape, dtype=source.dtype,
                                                       device=source.device)
        return observation_spec
