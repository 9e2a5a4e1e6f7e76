"""The env's rows: every env's state (the paper's and the aids'), with the observation and the
cost C it was last seen with; and what is done to rows as a whole: zeros, the outputs read
from them, their flat named copies (a snapshot's entries) and the check that they hold what
an episode can."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from torchpark._compat import tree_flatten
from torchpark.aids.step import POSITION, AidedState, AidState
from torchpark.sim.state import ParkingState


class Rows(NamedTuple):
    """The rows of B envs: ``state`` an :class:`~torchpark.aids.step.AidedState` of [B, ...]
    tensors, ``observation`` (B, D) float32, ``cost`` (B,) float32."""

    state: AidedState
    observation: Tensor
    cost: Tensor

    @classmethod
    def zeros(cls, rows: int, obstacles: int, obs_dim: int, device: torch.device) -> Rows:
        """``rows`` rows holding no lot (``obstacles`` boxes each): zeros."""
        return cls(AidedState(ParkingState.zeros(rows, obstacles, device),
                              AidState.zeros(rows, device)),
                   torch.zeros(rows, obs_dim, device=device), torch.zeros(rows, device=device))


def row_bytes(obstacles: int, obs_dim: int) -> int:
    """The bytes of one row (state, observation and cost) of a lot of ``obstacles`` boxes."""
    leaves, _ = tree_flatten(Rows.zeros(1, obstacles, obs_dim, torch.device("meta")))
    return sum(t.numel() * t.element_size() for t in leaves)


def output_fields(state: AidedState, observation: Tensor, cost: Tensor,
                  aid_keys: tuple[str, ...], position: bool) -> dict[str, Tensor]:
    """The outputs read from rows (views, not copies): observation (N, D), cost (N, 1) and
    occupancy (N, 1) float32, the aids' keys ``aid_keys`` (N, 1), and with ``position`` the
    rear axle's position (N, 2) metres."""
    fields = {"observation": observation, "cost": cost[:, None],
              "occupancy": state.sim.occupancy[:, None],
              **{key: getattr(state.aids, key)[:, None] for key in aid_keys}}
    if position:
        fields[POSITION] = state.sim.pose[:, :2]
    return fields


def flat_rows(rows: Rows, prefix: str = "") -> dict[str, Tensor]:
    """Rows as named copies: ``{prefix}state.<field>``, ``{prefix}aids.<field>``,
    ``{prefix}observation`` and ``{prefix}cost``."""
    (sim, aid), observation, cost = rows
    fields = {f"{prefix}state.{k}": v for k, v in zip(ParkingState._fields, sim, strict=True)}
    fields |= {f"{prefix}aids.{k}": v for k, v in zip(AidState._fields, aid, strict=True)}
    fields |= {f"{prefix}observation": observation, f"{prefix}cost": cost}
    return {k: v.clone() for k, v in fields.items()}


def unflat_rows(fields: dict[str, Tensor], device: torch.device, prefix: str = "") -> Rows:
    """The inverse of :func:`flat_rows`, copied to ``device`` (the env writes its rows in
    place, never the caller's tensors)."""
    def get(name: str) -> Tensor:
        return fields[prefix + name].to(device, copy=True)

    return Rows(AidedState(ParkingState(*(get(f"state.{k}") for k in ParkingState._fields)),
                           AidState(*(get(f"aids.{k}") for k in AidState._fields))),
                get("observation"), get("cost"))


def check_rows(rows: Rows, slots: int, name: str, observed: str) -> None:
    """ValueError naming the entry (``name.field`` for the state's, ``observed`` for the
    observation and cost) where rows hold what no episode can: a non-finite pose, speed,
    goal, observation or cost, a goal slot outside [0, ``slots``), a presence other than 0
    or 1, a negative step or intervention count, an occupancy outside [0, 1]. One read-back:
    for ``set_state`` and ``restore``, not the step."""
    (sim, aid), observation, cost = rows
    checks = [
        (f"{name}.pose", torch.isfinite(sim.pose).all(), "finite"),
        (f"{name}.speed", torch.isfinite(sim.speed).all(), "finite"),
        (f"{name}.goal", torch.isfinite(sim.goal).all(), "finite"),
        (f"{name}.goal_slot", ((sim.goal_slot >= 0) & (sim.goal_slot < slots)).all(),
         f"a slot index in [0, {slots})"),
        (f"{name}.present", ((sim.present == 0) | (sim.present == 1)).all(), "0 or 1"),
        (f"{name}.steps", (sim.steps >= 0).all(), ">= 0"),
        (f"{name}.occupancy", ((sim.occupancy >= 0) & (sim.occupancy <= 1)).all(),
         "in [0, 1]"),
        (f"{name}.aids.interventions", (aid.interventions >= 0).all(), ">= 0"),
        (observed, torch.isfinite(observation).all() & torch.isfinite(cost).all(), "finite"),
    ]
    held = torch.stack([ok for _, ok, _ in checks]).tolist()  # the one read-back
    for (entry, _, allowed), fine in zip(checks, held, strict=True):
        if not fine:
            raise ValueError(f"{entry} must be {allowed} in every row")
