"""Every config field rejects a wrong type and an out-of-range value by name, at
construction; combinations that make the task meaningless are refused too."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from torchpark import (
    AidsConfig,
    BrakeConfig,
    DockingConfig,
    LidarConfig,
    LotConfig,
    NearGoalStarts,
    ParkingConfig,
    RewardConfig,
    VehicleConfig,
)

CONFIGS = (VehicleConfig, LotConfig, LidarConfig, RewardConfig, ParkingConfig, BrakeConfig,
           DockingConfig, NearGoalStarts, AidsConfig)
FIELDS = [(cls, f) for cls in CONFIGS for f in dataclasses.fields(cls)]
IDS = [f"{cls.__name__}.{f.name}" for cls, f in FIELDS]


def default(cls, f):
    return f.default_factory() if f.default is dataclasses.MISSING else f.default


@pytest.mark.parametrize("cls, f", FIELDS, ids=IDS)
def test_every_field_rejects_a_wrong_type_by_name(cls, f):
    wrong = "1" if not isinstance(default(cls, f), str) else 1
    with pytest.raises(TypeError, match=rf"^{cls.__name__}\.{f.name} must be "):
        cls(**{f.name: wrong})
    if isinstance(default(cls, f), (int, float)) and not isinstance(default(cls, f), bool):
        with pytest.raises(TypeError, match=rf"{cls.__name__}\.{f.name} must be .*bool"):
            cls(**{f.name: True})  # a bool is not a number here


@pytest.mark.parametrize("cls, f", [(c, f) for c, f in FIELDS
                                    if type(default(c, f)) in (int, float)],
                         ids=[i for (c, f), i in zip(FIELDS, IDS, strict=True)
                              if type(default(c, f)) in (int, float)])
def test_every_number_rejects_an_out_of_range_value_by_name(cls, f):
    bad = math.nan if isinstance(default(cls, f), float) else -1
    with pytest.raises(ValueError, match=rf"{cls.__name__}\.{f.name} must be "):
        cls(**{f.name: bad})


def test_numbers_are_normalised():
    config = VehicleConfig(dt=1, max_speed=np.float32(0.5))
    assert type(config.dt) is float and type(config.max_speed) is float
    assert type(LidarConfig(n_rays=np.int64(8)).n_rays) is int


@pytest.mark.parametrize("make, match", [
    (lambda: ParkingConfig(max_steps=2**63), r"ParkingConfig\.max_steps"),
    (lambda: ParkingConfig(vehicle=VehicleConfig(max_speed=100.0, dt=2.0)),
     r"max_speed \* dt must be < the thinnest obstacle"),
    (lambda: RewardConfig(w_x=0.0, w_y=0.0, w_alpha=0.0, w_v=0.0), r"RewardConfig\.w_x"),
    (lambda: BrakeConfig(steer_clear=1), r"BrakeConfig\.steer_clear"),
    (lambda: LotConfig(car_width=3.0), "smaller than the slot"),
], ids=["max-steps-overflow", "tunnelling", "zero-weights", "steer-clear-of-one-angle",
        "car-wider-than-slot"])
def test_meaningless_combinations_are_refused(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_the_defaults_are_the_papers():
    config = ParkingConfig()
    vehicle = config.vehicle
    assert (vehicle.wheelbase, vehicle.dt, vehicle.max_speed) == (4.0, 0.1, 5.0)
    assert (config.reward.w_x, config.reward.w_y, config.reward.w_alpha, config.reward.w_v) \
        == (0.35, 0.35, 0.20, 0.10)
    assert config.reward.success_threshold == 4e-4 and config.max_steps == 1000
    assert config.lidar.n_rays == 16 and config.lot.num_slots == 38
    # No aid lives in the paper's config: they are a separate AidsConfig, all off by default.
    names = {f.name for cls in (ParkingConfig, VehicleConfig, LotConfig, LidarConfig,
                                RewardConfig) for f in dataclasses.fields(cls)}
    assert not names & {"action_repeat", "emergency_brake", "steer_clear", "docking",
                        "brake_penalty", "near_goal_starts", "aids"}
    aids = AidsConfig()
    assert aids.action_repeat == 1 and aids.brake is aids.docking is aids.near_goal_starts is None
