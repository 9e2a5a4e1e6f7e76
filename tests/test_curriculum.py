"""OccupancyCurriculum: exact level boundaries, resume from a state_dict, isolation; the
env's success threshold reaches a compiled step."""

from __future__ import annotations

import pytest
import torch
from torchrl.collectors import Collector
from torchrl.envs import TransformedEnv

from tests.conftest import COMPILED_BUILDS, COMPILED_GROUP, COMPILED_N
from torchpark import (
    AidsConfig,
    OccupancyCurriculum,
    ParkingEnv,
)
from torchpark.curriculum import PAPER_LEVELS


def make(num_envs: int, frames_per_level: int, seed: int = 0) -> TransformedEnv:
    return TransformedEnv(ParkingEnv(num_envs, seed=seed),
                          OccupancyCurriculum(frames_per_level=frames_per_level))


@pytest.mark.parametrize("num_envs", [1, 7, 25, 64])
def test_level_rises_exactly_at_each_boundary(num_envs):
    per_level = 50
    env = make(num_envs, per_level)
    curriculum = env.transform
    td = env.reset()
    assert env.base_env.occupancy == 0.0 and curriculum.phase == 1
    for step in range(1, 40):
        td = env.rand_step(td)["next"]
        frames = step * num_envs
        level = min(frames // per_level, len(PAPER_LEVELS) - 1)
        assert curriculum.frames_seen == frames and int(curriculum.frames) == frames
        assert curriculum.level == level and curriculum.phase == level + 1
        assert env.base_env.occupancy == PAPER_LEVELS[level]


def test_new_level_applies_to_lots_drawn_at_later_resets():
    env = make(8, 16)
    td = env.reset()
    td = env.rand_step(td)["next"]  # 8 frames: still level 0
    assert (td["occupancy"] == 0.0).all()
    td = env.rand_step(td)["next"]  # 16 frames: level 1 from now on
    assert env.base_env.occupancy == 0.2
    assert (td["occupancy"] == 0.0).all()  # the current lots were drawn at level 0
    mask = torch.zeros(8, 1, dtype=torch.bool)
    mask[:3] = True
    out = env.reset(td.set("_reset", mask))
    assert (out["occupancy"][:3] == 0.2).all() and (out["occupancy"][3:] == 0.0).all()
    slots = env.base_env.layout.num_slots
    parked = env.base_env.state.present[:, :slots].sum(1)
    assert (parked[:3] == round(0.2 * (slots - 1))).all() and (parked[3:] == 0).all()


def test_state_dict_round_trip_resumes_the_schedule():
    env = make(10, 30)
    td = env.reset()
    for _ in range(7):
        td = env.rand_step(td)["next"]
    state = env.state_dict()
    resumed = make(10, 30, seed=1)
    resumed.load_state_dict(state)
    assert resumed.transform.frames_seen == 70 and resumed.transform.phase == 3
    assert resumed.base_env.occupancy == 0.4
    td = resumed.reset()
    td = resumed.rand_step(td)["next"]
    assert resumed.transform.frames_seen == 80


def test_collector_state_dict_carries_the_frames():
    env = make(16, 100)
    collector = Collector(env, None, frames_per_batch=16 * 10, total_frames=16 * 20)
    for _ in collector:
        pass
    state = collector.state_dict()
    collector.shutdown()
    frames = [v for k, v in state["env_state_dict"].items() if k.endswith("frames")]
    assert [int(v) for v in frames] == [320]


def test_evaluation_env_does_not_advance_training_counter():
    train = make(4, 100)
    train.reset()
    evaluation = TransformedEnv(ParkingEnv(4, seed=1), OccupancyCurriculum(frames_per_level=100))
    evaluation.base_env.occupancy = 0.9
    evaluation.rollout(20, break_when_any_done=False)
    assert train.transform.frames_seen == 0 and train.base_env.occupancy == 0.0
    plain = ParkingEnv(4, seed=2)
    plain.occupancy = 0.6
    plain.rollout(10, break_when_any_done=False)
    assert train.transform.frames_seen == 0


@pytest.mark.parametrize("kwargs, match", [
    ({"levels": ()}, "levels must hold at least one"),
    ({"levels": (0.0, 1.5)}, r"levels\[1\] must be a number in \[0, 1\]"),
    ({"frames_per_level": 0}, "frames_per_level must be an int >= 1"),
    ({"frames_per_level": 2.5}, "frames_per_level must be an int >= 1"),
])
def test_bad_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        OccupancyCurriculum(**kwargs)


def test_replicas_count_the_frames_of_every_copy():
    # One of 3 copies stepping in lockstep: each step counts 3 x 8 frames.
    env = TransformedEnv(ParkingEnv(8, seed=0), OccupancyCurriculum(frames_per_level=48,
                                                                    replicas=3))
    td = env.reset()
    for step in range(1, 5):
        td = env.rand_step(td)["next"]
        assert env.transform.frames_seen == 24 * step
    assert env.transform.phase == 3 and env.base_env.occupancy == PAPER_LEVELS[2]
    with pytest.raises(ValueError, match="replicas must be an int >= 1"):
        OccupancyCurriculum(replicas=0)


def test_held_actions_count_as_several_frames():
    env = TransformedEnv(ParkingEnv(6, seed=0, aids=AidsConfig(action_repeat=5)),
                         OccupancyCurriculum(frames_per_level=60))
    td = env.reset()
    for step in range(1, 5):
        td = env.rand_step(td)["next"]
        assert env.transform.frames_seen == 30 * step
    assert env.transform.phase == 3 and env.base_env.occupancy == PAPER_LEVELS[2]


@pytest.mark.xdist_group(COMPILED_GROUP)
@pytest.mark.slow
def test_success_threshold_reaches_a_compiled_step():
    """The compiled step reads the threshold tensor at run time: no stale constant."""
    env = ParkingEnv(COMPILED_N, seed=0, config=COMPILED_BUILDS["paper"][0], compile_step=True)
    env.reset()
    action = torch.zeros(COMPILED_N, 2)
    assert not env.step(env.reset().set("action", action))["next", "success"].any()
    env.success_threshold = 1e4
    assert env.step(env.reset().set("action", action))["next", "success"].all()
    env.success_threshold = 4e-4
    assert not env.step(env.reset().set("action", action))["next", "success"].any()


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf"), True, "1"])
def test_bad_success_threshold_raises(value):
    with pytest.raises(ValueError, match="success_threshold must be a finite float > 0"):
        ParkingEnv(1).success_threshold = value
