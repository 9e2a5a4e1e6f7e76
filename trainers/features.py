"""The policy's extra inputs by name (``AgentConfig.features``): one registry from a
feature's name to the transforms that append it to the policy's input and the env outputs
it reads besides the observation.

Each feature reads the input built so far (``source``: the paper's observation first) and
writes ``POLICY_INPUT`` with its own columns appended, so the input's layout is the list's
order. A new feature is its transform (``torchpark.transforms``), its test and one line of
:data:`FEATURES`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torchrl.envs import CatTensors, DTypeCastTransform, Transform

from torchpark import (
    ClearanceFeatures,
    GearTravelFeatures,
    GoalFrameFeatures,
    ParkingEnv,
    ScanMemory,
    SlotGaps,
)
from torchpark.aids.step import BRAKED, POSITION

if TYPE_CHECKING:
    from trainers.config import AgentConfig

POLICY_INPUT = "observation_policy"  # the raw policy input the features build up


@dataclass(frozen=True)
class Feature:
    """One input feature: ``build(base, agent, source)`` gives the transforms that append it
    to ``source`` in ``POLICY_INPUT`` (``base``: the env below them, ``agent``: the agent's
    config, for a feature's own knob); ``reads``: the env outputs it reads besides the
    observation (an agent acting outside the env is handed them in ``info``)."""

    build: Callable[[ParkingEnv, AgentConfig, str], list[Transform]]
    reads: tuple[str, ...] = ()


def _position(base: ParkingEnv, agent: AgentConfig, source: str) -> list[Transform]:
    return [CatTensors([source, POSITION], POLICY_INPUT, del_keys=False, sort=False)]


def _brake(base: ParkingEnv, agent: AgentConfig, source: str) -> list[Transform]:
    return [DTypeCastTransform(torch.bool, torch.float32, in_keys=[BRAKED],
                               out_keys=["braked_input"]),
            CatTensors([source, "braked_input"], POLICY_INPUT, del_keys=False, sort=False)]


FEATURES: dict[str, Feature] = {
    "goal": Feature(lambda base, agent, source: [GoalFrameFeatures(source, POLICY_INPUT)]),
    "clearance": Feature(lambda base, agent, source: [
        ClearanceFeatures(base.config, source, POLICY_INPUT)]),
    "gear": Feature(lambda base, agent, source: [
        GearTravelFeatures(base.config.vehicle.dt * base.action_repeat, source, POLICY_INPUT)]),
    "scan_memory": Feature(lambda base, agent, source: [
        ScanMemory(base.config, agent.memory_scans, source, POLICY_INPUT)]),
    "slots": Feature(lambda base, agent, source: [
        SlotGaps(base.config, source, POSITION, POLICY_INPUT)], reads=(POSITION,)),
    "position": Feature(_position, reads=(POSITION,)),
    "brake": Feature(_brake, reads=(BRAKED,)),
}


def feature_transforms(base: ParkingEnv, agent: AgentConfig) -> tuple[list[Transform], str]:
    """The transforms of ``agent.features`` in their order over the env ``base``, and the key
    of the input they build (``"observation"`` with none)."""
    source, transforms = "observation", []
    for name in agent.features:
        transforms += FEATURES[name].build(base, agent, source)
        source = POLICY_INPUT
    return transforms, source


def feature_reads(agent: AgentConfig) -> tuple[str, ...]:
    """The env outputs besides the observation that ``agent.features`` read, once each."""
    return tuple(dict.fromkeys(key for name in agent.features
                               for key in FEATURES[name].reads))
