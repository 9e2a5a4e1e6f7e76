"""The policy's input features by name (trainers/features.py): each feature of the registry
appends its columns in the list's order, the episode features hand their state out and take
it back, and a config saved with the features as flags loads as the same input."""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path

import pytest
import torch
from torchrl.envs import Compose, TransformedEnv

from torchpark import (
    ClearanceFeatures,
    EpisodeFeature,
    GearTravelFeatures,
    GoalFrameFeatures,
    ParkingConfig,
    ScanMemory,
    SlotGaps,
)
from trainers.checkpoint import load_checkpoint
from trainers.config import AgentConfig, load_config, upgraded_config
from trainers.features import FEATURES, POLICY_INPUT, feature_reads
from trainers.utils import make_base_env, policy_input

WIDTHS = {"goal": 7, "clearance": 16, "gear": 2, "scan_memory": 16, "slots": 16,
          "position": 2, "brake": 1}


def _env(features: list[str]) -> TransformedEnv:
    cfg = load_config("smoke", ["agent.aids.brake={}", "agent.aids.observe_position=true",
                                f"agent.features=[{','.join(features)}]"])
    base = make_base_env(cfg, training=False, num_envs=3, seed=2)
    return TransformedEnv(base, Compose(*policy_input(cfg, base)))


def _starts(names: list[str]) -> dict[str, int]:
    """Each feature's first column in an input of ``names`` in that order."""
    starts, column = {}, 23
    for name in names:
        starts[name], column = column, column + WIDTHS[name]
    return starts


def test_every_feature_appends_its_columns_in_the_lists_order():
    assert set(FEATURES) == set(WIDTHS)
    names = list(FEATURES)
    td, back = _env(names).reset(), _env(names[::-1]).reset()
    x, y = td[POLICY_INPUT], back[POLICY_INPUT]
    assert x.shape == y.shape == (3, 23 + sum(WIDTHS.values()))
    assert torch.equal(x[:, :23], td["observation"])
    ours, theirs = _starts(names), _starts(names[::-1])
    for name in names:  # each feature's block sits where its place in the list puts it
        torch.testing.assert_close(x[:, ours[name]:ours[name] + WIDTHS[name]],
                                   y[:, theirs[name]:theirs[name] + WIDTHS[name]])
    assert torch.equal(x[:, -3:-1], td["position"])
    assert torch.equal(x[:, -1], td["braked"][:, 0].float())


def test_no_feature_normalises_the_observation_itself():
    env = _env([])
    td = env.reset()
    assert POLICY_INPUT not in td.keys()
    assert env.transform[-1].in_keys == ["observation"]


def test_the_reads_are_the_env_outputs_besides_the_observation_once_each():
    agent = AgentConfig(features=["slots", "goal", "position", "brake"])
    assert feature_reads(agent) == ("position", "braked")
    assert feature_reads(AgentConfig(features=["goal", "gear"])) == ()


def test_the_episode_features_are_the_ones_that_read_the_episode():
    config = ParkingConfig()
    stateful = [GearTravelFeatures(0.1), ScanMemory(config, 2)]
    stateless = [GoalFrameFeatures(), ClearanceFeatures(config), SlotGaps(config)]
    assert all(isinstance(t, EpisodeFeature) for t in stateful)
    assert not any(isinstance(t, EpisodeFeature) for t in stateless)
    assert [t.state_width for t in stateful] == [2, 2 * (4 + 16)]


@pytest.mark.parametrize("feature", ["gear", "scan_memory"])
def test_an_episode_features_state_carried_outside_the_env_gives_the_envs_features(feature):
    """As ``TrainedAgent.predict`` carries it: each observation seen by a fresh transform
    that resumes from the state the last one handed out, then resets with the going-on rows
    kept, writes the features the env's own transform wrote stepping the episode; a row that
    starts gets a new episode's features."""
    def episode_feature(env: TransformedEnv) -> EpisodeFeature:
        return next(t for t in env.transform if isinstance(t, EpisodeFeature))

    env = _env([feature])
    seen = [env.reset()]
    for k in range(4):
        action = torch.tensor([[0.4, 0.3 - 0.2 * k]]).expand(3, 2)
        seen.append(env.step(seen[-1].set("action", action))["next"])
    going_on = torch.tensor([True, True, False])
    carried = episode_feature(_env([feature]))
    carried._reset(None, seen[0].select("observation"))
    for before, now in pairwise(seen):
        state = carried.episode_state(before["observation"])
        carried = episode_feature(_env([feature]))
        carried.resume(now["observation"], state, going_on)
        td = now.select("observation").set("_reset", ~going_on[:, None])
        out = carried._reset(td, td.clone())
        torch.testing.assert_close(out[POLICY_INPUT][:2], now[POLICY_INPUT][:2], rtol=0,
                                   atol=0)
        started = episode_feature(_env([feature]))._reset(None, now.select("observation"))
        torch.testing.assert_close(out[POLICY_INPUT][2], started[POLICY_INPUT][2], rtol=0,
                                   atol=0)
    assert not torch.equal(out[POLICY_INPUT][0], started[POLICY_INPUT][0])


def test_a_config_saved_with_the_features_as_flags_loads_as_the_same_input():
    flags = {"goal_features": True, "clearance_features": True, "gear_features": False,
             "scan_memory": 3, "slot_features": True, "observe_brake": False,
             "aids": {"observe_position": True}, "gear_head": True}
    upgraded = upgraded_config({"seed": 1, "agent": flags})
    assert upgraded == {"seed": 1, "agent": {
        "aids": {"observe_position": True}, "gear_head": True, "memory_scans": 3,
        "features": ["goal", "clearance", "scan_memory", "slots", "position"]}}
    today = {"agent": {"features": ["goal"]}}
    assert upgraded_config(today) is today
    with pytest.raises(ValueError, match=r"agent\.goal_features must be true or false, got 2"):
        upgraded_config({"agent": {**flags, "goal_features": 2}})
    with pytest.raises(ValueError, match=r"agent\.scan_memory must be an int >= 0, got -1"):
        upgraded_config({"agent": {**flags, "scan_memory": -1}})


def test_the_committed_checkpoints_load_with_their_features_named():
    results = Path(__file__).resolve().parents[1] / "results"
    fast = load_checkpoint(results / "fast" / "checkpoint_final.pt")["config"]["agent"]
    alone = load_checkpoint(results / "policy_alone" / "checkpoint_best.pt")["config"]["agent"]
    assert fast["features"] == ["goal", "brake"]
    assert alone["features"] == ["goal", "clearance", "gear", "scan_memory", "slots",
                                 "position"]
    assert alone["memory_scans"] == 3
