"""A ``ParkingEnv``'s snapshot, and its restore: everything the env's future depends on, as
plain tensors and numbers (safe for ``torch.save`` and ``torch.load(weights_only=True)``),
and a restore that checks every entry before it writes any.

A snapshot holds every lot's state (and the aids'), the last observation and cost, the reset
engine's episodes drawn ahead and where its hand-out stands (:mod:`torchpark.resets`), the
random generator, the occupancy of later lots, the success threshold, whether a lot was
drawn, and how the env was built (``build``: its size, configs and reset path), so that an
env built otherwise refuses it.
"""

from __future__ import annotations

import dataclasses

import torch

from torchpark.aids.config import AidsConfig
from torchpark.config import ParkingConfig, check_flag, check_occupancy
from torchpark.resets import Resets, check_generator_state
from torchpark.rows import Rows, check_rows, flat_rows, unflat_rows
from torchpark.sim.world import World

# What a snapshot's build lacks is read as these: snapshots from before the reset path was
# a choice are of the host path.
BUILD_DEFAULTS = {"config": dataclasses.asdict(ParkingConfig()),
                  "aids": dataclasses.asdict(AidsConfig()), "reset_in_step": False,
                  "ring_blocks": 0}


def build_of(num_envs: int, config: ParkingConfig, aids: AidsConfig, resets: Resets) -> dict:
    """How an env was built (what its state's meaning depends on), as plain data: the number
    of lots, the task's config and the aids', the reset path and its ring's blocks."""
    return {"num_envs": num_envs, "config": dataclasses.asdict(config),
            "aids": dataclasses.asdict(aids), "reset_in_step": resets.reset_in_step,
            "ring_blocks": resets.ring_blocks}


def take_snapshot(rows: Rows, resets: Resets, world: World, started: bool, build: dict
                  ) -> dict:
    """The snapshot of an env's ``rows``, reset engine, ``world`` (its success threshold),
    whether a lot was drawn (``started``) and its ``build`` (:func:`build_of`): copies."""
    return {**flat_rows(rows), **resets.snapshot(), "generator": resets.draw.generator.get_state(),
            "occupancy": resets.draw.occupancy,
            "success_threshold": world.success_threshold.clone(), "started": started,
            "build": build}


def first_difference(saved: object, ours: object, default: object = None, name: str = ""
                     ) -> str | None:
    """Where two nested dicts of plain data first differ, as ``"name=<saved> in the
    snapshot, <ours> here"``; None where they are equal. A key the snapshot lacks (a field
    added since it was taken) is read as its value in ``default`` (a nested dict of the
    same shape: the fields' defaults)."""
    if isinstance(saved, dict) and isinstance(ours, dict):
        default = default if isinstance(default, dict) else {}
        for key in sorted(set(saved) | set(ours), key=str):
            found = first_difference(saved.get(key, default.get(key)), ours.get(key),
                                     default.get(key), f"{name}.{key}".lstrip("."))
            if found is not None:
                return found
        return None
    if saved != ours:
        return f"{name or 'build'}={saved!r} in the snapshot, {ours!r} here"
    return None


def check_snapshot(snapshot: object, expected: dict, resets: Resets, slots: int) -> None:
    """TypeError or ValueError naming the first entry of ``snapshot`` that does not fit the
    env whose snapshot is ``expected`` (``resets`` its engine, ``slots`` its goal slots);
    nothing is written."""
    if not isinstance(snapshot, dict):
        raise TypeError(f"snapshot must be a dict from ParkingEnv.snapshot, got "
                        f"{type(snapshot).__name__}")
    differs = first_difference(snapshot.get("build"), expected["build"], BUILD_DEFAULTS)
    if differs is not None:
        raise ValueError(f"snapshot['build'] is of an env built otherwise: {differs}")
    missing, extra = sorted(set(expected) - set(snapshot)), sorted(set(snapshot) - set(expected))
    if missing or extra:
        raise ValueError(f"snapshot must hold exactly {sorted(expected)}; missing {missing}, "
                         f"extra {extra}")
    for key, ours in expected.items():
        theirs = snapshot[key]
        if isinstance(ours, torch.Tensor) and (
                not isinstance(theirs, torch.Tensor) or theirs.shape != ours.shape
                or theirs.dtype != ours.dtype):
            raise ValueError(f"snapshot[{key!r}] must be a {ours.dtype} tensor of shape "
                             f"{tuple(ours.shape)}, got {theirs!r}")
    check_occupancy(snapshot["occupancy"], "snapshot['occupancy']")
    check_flag(snapshot["started"], "snapshot['started']")
    threshold = snapshot["success_threshold"]
    if not bool(torch.isfinite(threshold) & (threshold > 0)):
        raise ValueError(f"snapshot['success_threshold'] must be a finite number > 0, got "
                         f"{threshold!r}")
    device = resets.draw.generator.device
    check_generator_state(snapshot["generator"], device, "snapshot['generator']")
    resets.check(snapshot, slots)
    check_rows(unflat_rows(snapshot, device), slots, "snapshot['state']",
               "snapshot['observation'] and ['cost']")


def restore_snapshot(snapshot: object, expected: dict, resets: Resets, world: World
                     ) -> tuple[Rows, bool]:
    """Put an env's parts where ``snapshot`` says, every entry checked first
    (:func:`check_snapshot`): the occupancy of later lots and the generator (``resets``'s
    draw), the engine's episodes drawn ahead, ``world``'s success threshold. Returns the
    rows and whether a lot was drawn, for the env to keep."""
    check_snapshot(snapshot, expected, resets, world.goal_poses.shape[0])
    assert isinstance(snapshot, dict)  # check_snapshot refuses anything else
    # Everything fits: written from here on, nothing can fail half-way. The engine's state
    # is replaced whole, so nothing drawn ahead at the old occupancy or threshold survives.
    resets.draw.occupancy = float(snapshot["occupancy"])
    world.success_threshold.fill_(float(snapshot["success_threshold"]))
    resets.draw.generator.set_state(snapshot["generator"])
    resets.load(snapshot)
    return unflat_rows(snapshot, resets.draw.generator.device), bool(snapshot["started"])
