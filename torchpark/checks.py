"""The checks of what a user hands ``ParkingEnv`` after its configs (:mod:`torchpark.config`
checks those): a device, an action, a success threshold, the envs of a picture. Each gives
the value in the form the env uses, or a one-line error naming the argument and what it
may be."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from torchpark.config import is_integer, is_number
from torchpark.sim.state import ParkingState


def check_count(value: object, name: str, low: int, high: int | None = None) -> int:
    """``value`` as an int, or ValueError naming ``name`` unless it is an int >= ``low`` (and
    <= ``high`` where given)."""
    if not is_integer(value) or value < low or (high is not None and value > high):
        allowed = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise ValueError(f"{name} must be an int {allowed}, got {value!r}")
    return int(value)


def check_optional(value: object, kind: type, name: str) -> None:
    """TypeError naming ``name`` unless ``value`` is None or a ``kind``."""
    if value is not None and not isinstance(value, kind):
        article = "an" if kind.__name__[0] in "AEIOU" else "a"
        raise TypeError(f"{name} must be {article} {kind.__name__} or None, got {value!r}")


def check_index(index: object, num_envs: int) -> int:
    """``index`` as an int, or IndexError unless it is an int in [0, ``num_envs``)."""
    if not is_integer(index) or not 0 <= index < num_envs:
        raise IndexError(f"index must be an int in [0, {num_envs - 1}], got {index!r}")
    return int(index)


def check_device(device: torch.device | str | int, name: str = "device") -> torch.device:
    """``device`` as a torch device ("cpu:0" as "cpu"); ValueError naming ``name`` unless it
    is a CPU or CUDA device this machine has."""
    try:
        parsed = torch.device(device)
    except (RuntimeError, TypeError):
        parsed = None
    if parsed is None or parsed.type not in ("cpu", "cuda"):
        raise ValueError(f"{name} must be a torch device such as 'cpu' or 'cuda:0', got "
                         f"{device!r}")
    if parsed.type == "cpu" and (parsed.index or 0) != 0:
        raise ValueError(f"{name} is {device!r}, but torch has one CPU device: 'cpu'")
    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if parsed.type == "cuda" and (parsed.index or 0) >= count:
        raise ValueError(f"{name} is {device!r}, but torch sees {count or 'no'} CUDA "
                         f"device(s) here")
    return torch.device("cpu") if parsed.type == "cpu" else parsed


def check_action(action: object, num_envs: int, device: torch.device) -> torch.Tensor:
    """A step's action as the step takes it, (N, 2) float32 and detached (float64 rounded);
    ValueError unless it is a float32 or float64 tensor of shape (``num_envs``, 2) on
    ``device``."""
    if not isinstance(action, torch.Tensor):
        raise ValueError(f"the tensordict must hold an 'action' tensor of shape ({num_envs}, 2)"
                         f" = (num_envs, [v, delta]), got {type(action).__name__}: set "
                         f"td['action'] before env.step(td)")
    if action.shape != (num_envs, 2):
        raise ValueError(f"action must have shape ({num_envs}, 2) = (num_envs, [v, delta]), "
                         f"got {tuple(action.shape)}")
    if action.device != device:
        raise ValueError(f"action must be on the env's device {device}, got {action.device}")
    if action.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"action must be float32 (or float64, rounded to float32), got "
                         f"{action.dtype}")
    return action.detach().to(torch.float32)


def check_threshold(value: object) -> float:
    """A success threshold as a float: a finite number > 0, or a 0-d float tensor holding
    one (read back: on CUDA a synchronisation) that does not require grad."""
    if isinstance(value, torch.Tensor):
        if value.dim() != 0 or not value.is_floating_point() or value.requires_grad:
            raise ValueError(f"success_threshold must be a 0-d float tensor that does not "
                             f"require grad, got shape {tuple(value.shape)} {value.dtype}"
                             f"{' requiring grad' if value.requires_grad else ''}")
        number: object = float(value)
    else:
        number = value
    if not is_number(number) or not math.isfinite(number) or number <= 0:
        raise ValueError(f"success_threshold must be a finite float > 0, got {value!r}")
    return float(number)


def check_pictures(indices: object, columns: object, num_envs: int) -> tuple[list[int],
                                                                             int | None]:
    """The envs of a grid of pictures, ``indices`` (a sequence of ints in [0, ``num_envs``);
    None: all) as a list, and ``columns`` (an int in [1, len(indices)] or None)."""
    if indices is not None and (isinstance(indices, (str, bytes))
                                or not isinstance(indices, (Sequence, np.ndarray))):
        raise TypeError(f"indices must be a sequence of env indices (ints in [0, "
                        f"{num_envs - 1}]) or None, got {indices!r}")
    if indices is not None and not all(is_integer(i) for i in indices):
        raise IndexError(f"indices must be ints in [0, {num_envs - 1}], got {list(indices)}")
    indices = list(range(num_envs)) if indices is None else [int(i) for i in indices]
    bad = [i for i in indices if not 0 <= i < num_envs]
    if bad or not indices:
        raise IndexError(f"indices must be non-empty ints in [0, {num_envs - 1}], got "
                         f"{bad or indices}")
    if columns is not None and not (is_integer(columns) and 1 <= columns <= len(indices)):
        raise ValueError(f"columns must be an int in [1, {len(indices)}] (the pictures' "
                         f"count) or None, got {columns!r}")
    return indices, None if columns is None else int(columns)


def check_state(state: object, ours: ParkingState) -> None:
    """TypeError unless ``state`` is a :class:`ParkingState`, ValueError naming the first of
    its fields whose tensor differs in shape, dtype or device from that of ``ours``."""
    if not isinstance(state, ParkingState):
        raise TypeError(f"state must be a ParkingState, got {type(state).__name__}")
    for name, new, old in zip(ParkingState._fields, state, ours, strict=True):
        if not isinstance(new, torch.Tensor) or new.shape != old.shape \
                or new.dtype != old.dtype or new.device != old.device:
            raise ValueError(f"state.{name} must be a {old.dtype} tensor of shape "
                             f"{tuple(old.shape)} on {old.device}, got {new!r}")


def check_row_mask(rows: object, num_envs: int, device: torch.device) -> torch.Tensor:
    """The rows a call applies to as a (``num_envs``,) bool tensor on ``device``: ``rows`` a
    bool tensor of ``num_envs`` elements, or None for every row."""
    if rows is None:
        return torch.ones(num_envs, dtype=torch.bool, device=device)
    if not isinstance(rows, torch.Tensor) or rows.dtype != torch.bool \
            or rows.numel() != num_envs:
        raise ValueError(f"rows must be a bool tensor of {num_envs} elements (one per env), "
                         f"got {rows!r}")
    return rows.to(device).reshape(num_envs)
