"""A policy-side action map: the policy acts in [-1, 1] per dimension, the env receives
``high * sign(u) |u| ** exponent``.

With exponent 3 on the speed, a policy's noise around u = 0 moves the car by millimetres
rather than decimetres per step, while u = +-1 still reaches the full speed: the
resolution the paper's success test (about 1 mm, 4 mm/s) asks for, and calm exploration
beside walls and parked cars. Exponent 1 is a plain rescaling to [-1, 1].
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor
from torchrl.data import Bounded, Composite, TensorSpec
from torchrl.envs.transforms import Transform


def power_map(u: Tensor, high: Tensor, exponents: Tensor) -> Tensor:
    """Policy actions u [..., D] (clamped to [-1, 1]) -> env actions high * sign(u) |u| **
    exponents; ``high``, ``exponents`` (D,)."""
    u = u.clamp(-1.0, 1.0)
    return high * torch.sign(u) * u.abs().pow(exponents)


def power_map_inverse(action: Tensor, high: Tensor, exponents: Tensor) -> Tensor:
    """Env actions [..., D] -> the policy actions u that :func:`power_map` turns into them,
    sign(a) |a / high| ** (1 / exponents), kept inside (-1, 1) (|u| <= 0.999: a tanh
    policy's loc stays finite)."""
    y = (action / high).clamp(-0.999, 0.999)
    return torch.sign(y) * y.abs().pow(1.0 / exponents)


class PowerActionMap(Transform):
    """Maps the policy's action u in [-1, 1]^D to ``high * sign(u) |u| ** exponents``.

    Args:
        high: (D,) the env's symmetric action bounds (e.g. 5 m/s, 0.785 rad).
        exponents: (D,) exponents >= 1 per action dimension.
        action_key: the action's key.

    The policy sees ``Bounded(-1, 1)``; out-of-range inputs are clamped to [-1, 1] first
    (the env clamps its own actions the same way).
    """

    def __init__(self, high: Sequence[float] | Tensor, exponents: Sequence[float] | Tensor,
                 action_key: str = "action") -> None:
        high = torch.as_tensor(high, dtype=torch.float32)
        exponents = torch.as_tensor(exponents, dtype=torch.float32)
        if high.ndim != 1 or high.shape != exponents.shape:
            raise ValueError(f"high and exponents must be 1-D of one length, got shapes "
                             f"{tuple(high.shape)} and {tuple(exponents.shape)}")
        if not (high.isfinite().all() and (high > 0).all()):
            raise ValueError(f"high must be finite and > 0, got {high.tolist()}")
        if not (exponents.isfinite().all() and (exponents >= 1).all()):
            raise ValueError(f"exponents must be finite and >= 1, got {exponents.tolist()}")
        super().__init__(in_keys_inv=[action_key], out_keys_inv=[action_key])
        self.register_buffer("high", high)
        self.register_buffer("exponents", exponents)

    def _inv_apply_transform(self, action: Tensor) -> Tensor:
        return power_map(action, self.high, self.exponents)

    def transform_action_spec(self, action_spec: TensorSpec) -> TensorSpec:
        if isinstance(action_spec, Composite):
            action_spec = action_spec.clone()
            key = self.in_keys_inv[0]
            action_spec[key] = self.transform_action_spec(action_spec[key])
            return action_spec
        if action_spec.shape[-1] != self.high.shape[0]:
            raise ValueError(f"the env's action has {action_spec.shape[-1]} dimensions, "
                             f"this map {self.high.shape[0]}")
        ones = torch.ones(action_spec.shape, device=action_spec.device)
        return Bounded(low=-ones, high=ones, shape=action_spec.shape, dtype=action_spec.dtype,
                       device=action_spec.device)
