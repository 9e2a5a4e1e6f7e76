"""Policy-side action maps: the policy acts in [-1, 1] per dimension, the env receives
``high * sign(u) |u| ** exponent`` (:class:`PowerActionMap`), optionally chosen by a gear
(:class:`GearActionMap`).

With exponent 3 on the speed, a policy's noise around u = 0 moves the car by millimetres
rather than decimetres per step, while u = +-1 still reaches the full speed: the
resolution the paper's success test (about 1 mm, 4 mm/s) asks for, and calm exploration
beside walls and parked cars. Exponent 1 is a plain rescaling to [-1, 1].

The gear: a smooth state feedback cannot stabilise a car-like vehicle at a pose (Brockett,
1983); the stabilising law switches between driving forwards and reversing. A network that
regresses one (speed, steer) onto a teacher that does either at the same observation
outputs their mean, a speed near 0, and stops there. With a gear head it outputs a gear and
a (speed, steer) per gear, and the sign of the gear picks one pair: two answers are not
averaged into neither.
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


# The gear head's action: (gear, forward speed, forward steer, reverse speed, reverse steer).
GEAR_DIM = 5


def gear_select(u: Tensor) -> Tensor:
    """Gear-head actions u [..., 5] in [-1, 1] (gear, forward speed, forward steer, reverse
    speed, reverse steer) -> (speed, steer) [..., 2] in [-1, 1]: gear >= 0 drives forwards
    at the forward pair's speed, gear < 0 reverses at the reverse pair's; a pair's speed
    <= 0 holds the car (speed 0)."""
    forward = u[..., :1] >= 0
    speed = torch.where(forward, u[..., 1:2], u[..., 3:4]).clamp(0.0, 1.0)
    steer = torch.where(forward, u[..., 2:3], u[..., 4:5]).clamp(-1.0, 1.0)
    return torch.cat((torch.where(forward, speed, -speed), steer), dim=-1)


def gear_inverse(u: Tensor) -> Tensor:
    """(speed, steer) [..., 2] in [-1, 1] -> the gear-head action [..., 5] that
    :func:`gear_select` maps to it: the gear +-1 by the speed's sign (forwards at 0), both
    pairs (|speed|, steer)."""
    speed, steer = u.clamp(-1.0, 1.0).unbind(-1)
    gear = torch.where(speed >= 0, 1.0, -1.0)
    return torch.stack((gear, speed.abs(), steer, speed.abs(), steer), dim=-1)


def _unit_bounds(spec: Bounded, width: int) -> Bounded:
    shape = (*spec.shape[:-1], width)
    ones = torch.ones(shape, device=spec.device)
    return Bounded(low=-ones, high=ones, shape=shape, dtype=spec.dtype, device=spec.device)


class _ActionMap(Transform):
    """An inverse-only transform of the action: the policy's action spec is
    ``_policy_spec`` of the env's (of its action entry, in a composite spec)."""

    def _policy_spec(self, action_spec: TensorSpec) -> TensorSpec:
        raise NotImplementedError

    def transform_action_spec(self, action_spec: TensorSpec) -> TensorSpec:
        if isinstance(action_spec, Composite):
            action_spec = action_spec.clone()
            key = self.in_keys_inv[0]
            action_spec[key] = self._policy_spec(action_spec[key])
            return action_spec
        return self._policy_spec(action_spec)


class PowerActionMap(_ActionMap):
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

    def _policy_spec(self, action_spec: TensorSpec) -> TensorSpec:
        if action_spec.shape[-1] != self.high.shape[0]:
            raise ValueError(f"the env's action has {action_spec.shape[-1]} dimensions, "
                             f"this map {self.high.shape[0]}")
        return _unit_bounds(action_spec, action_spec.shape[-1])


class GearActionMap(_ActionMap):
    """Maps the policy's gear-head action u in [-1, 1]^5 to the (speed, steer) in [-1, 1]^2 of
    the action map below it (:func:`gear_select`); the env below must act in [-1, 1]^2 (a
    :class:`PowerActionMap`, which turns it into metres per second and radians).

    Args:
        action_key: the action's key.
    """

    def __init__(self, action_key: str = "action") -> None:
        super().__init__(in_keys_inv=[action_key], out_keys_inv=[action_key])

    def _inv_apply_transform(self, action: Tensor) -> Tensor:
        return gear_select(action)

    def _policy_spec(self, action_spec: TensorSpec) -> TensorSpec:
        unit = (isinstance(action_spec, Bounded) and action_spec.shape[-1] == 2
                and bool((action_spec.space.low == -1).all())
                and bool((action_spec.space.high == 1).all()))
        if not unit:
            raise ValueError(f"GearActionMap needs an env acting in [-1, 1]^2 below it (a "
                             f"PowerActionMap), got {action_spec}")
        return _unit_bounds(action_spec, GEAR_DIM)
