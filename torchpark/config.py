"""The paper's task as typed, frozen configuration: its values (and docs/spec.md's choices) as
defaults, so ``ParkingConfig()`` is the paper. The agent-side aids are configured apart, in
:mod:`torchpark.aids.config`.

Units: metres, seconds, radians. Every value is checked when the dataclass is built, so an
impossible configuration fails at construction with the field's name and its allowed range.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import typing
from dataclasses import dataclass, field
from typing import TypeGuard

import numpy as np


def is_number(value: object) -> TypeGuard[float]:
    """A real number (Python or numpy) that is not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def is_integer(value: object) -> TypeGuard[int]:
    """An integer (Python or numpy) that is not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def check_flag(value: object, name: str) -> bool:
    """``value`` as a bool, or TypeError naming ``name`` when it is not one (a truthy string
    or an int is not taken for a flag)."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be a bool, got {value!r}")
    return bool(value)


def check_types(config: object) -> None:
    """Every field of a config dataclass against its annotation, by name: bool fields take
    bools, int fields ints (not bools), float fields real numbers (not bools; ints and numpy
    numbers are stored as float), nested configs their class, ``X | None`` also None. Raises
    TypeError naming ``Class.field``; otherwise stores the normalised values."""
    if not dataclasses.is_dataclass(config):
        raise TypeError(f"check_types takes a config dataclass, got {type(config).__name__}")
    owner = type(config).__name__
    hints = typing.get_type_hints(type(config))
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        kinds = typing.get_args(hints[f.name]) or (hints[f.name],)
        if value is None and type(None) in kinds:
            continue
        kind = next(k for k in kinds if k is not type(None))
        if kind is bool and isinstance(value, (bool, np.bool_)):
            value = bool(value)
        elif kind is int and is_integer(value):
            value = int(value)
        elif kind is float and is_number(value):
            value = float(value)
        elif kind not in (bool, int, float) and isinstance(value, kind):
            pass
        else:
            expected = {bool: "a bool", int: "an int", float: "a number"}.get(
                kind, f"a {kind.__name__}") + (" or None" if type(None) in kinds else "")
            raise TypeError(f"{owner}.{f.name} must be {expected}, got {value!r} "
                            f"({type(value).__name__})")
        object.__setattr__(config, f.name, value)


# Seeds are ints in [0, SEED_LIMIT): torch's CPU generator (mt19937) keeps 32 bits of a
# seed, so that seeds s and s + 2**32 would draw the same lots.
SEED_LIMIT = 2**32


def check_seed(value: object, name: str = "seed") -> int:
    """``value`` as an int, or ValueError naming ``name`` when it is not one in
    [0, SEED_LIMIT)."""
    if not is_integer(value) or not 0 <= value < SEED_LIMIT:
        raise ValueError(f"{name} must be an int in [0, 2**32), got {value!r}")
    return int(value)


def require(ok: bool, name: str, allowed: str, value: object) -> None:
    if not ok:
        raise ValueError(f"{name} must be {allowed}, got {value!r}")


def positive(name: str, value: float) -> None:
    require(math.isfinite(value) and value > 0, name, "a finite number > 0", value)


@dataclass(frozen=True)
class VehicleConfig:
    """Kinematic bicycle with its footprint, referenced at the rear axle centre."""

    wheelbase: float = 4.0
    width: float = 2.0
    length: float = 5.0
    rear_overhang: float = 0.5  # the box spans -0.5 m .. +4.5 m along the heading from the axle
    dt: float = 0.1
    max_speed: float = 5.0  # |v| limit, m/s
    max_steer: float = 0.785  # |delta| limit, rad

    def __post_init__(self) -> None:
        check_types(self)
        for name in ("wheelbase", "width", "length", "dt", "max_speed", "max_steer"):
            positive(f"VehicleConfig.{name}", getattr(self, name))
        require(
            0.0 <= self.rear_overhang < self.length,
            "VehicleConfig.rear_overhang", f"in [0, length={self.length})", self.rear_overhang,
        )
        require(self.max_steer < math.pi / 2, "VehicleConfig.max_steer", "< pi/2", self.max_steer)

    @property
    def centre_offset(self) -> float:
        """Distance from the rear axle to the box centre along the heading, metres."""
        return self.length / 2.0 - self.rear_overhang


@dataclass(frozen=True)
class LotConfig:
    """The four-section lot of the paper; slot counts per section and the start-pose sampler."""

    slot_width: float = 2.5
    slot_length: float = 5.5
    lane_width: float = 6.0
    car_width: float = 2.0  # parked car box, centred in its slot along the slot heading
    car_length: float = 5.0
    upper_slots: int = 10
    left_slots: int = 8
    middle_slots: int = 12  # a back-to-back double row: half face +90 deg, half -90 deg
    right_slots: int = 8
    margin: float = 0.25  # gap between the outermost slots (or slot mouths) and the walls
    wall_thickness: float = 1.0
    start_candidates: int = 16  # uniform start poses tried per env per reset
    start_pool_size: int = 4096  # valid poses drawn once, used when all candidates fail
    pool_seed: int = 0
    def __post_init__(self) -> None:
        check_types(self)
        for name in ("slot_width", "slot_length", "lane_width", "car_width", "car_length",
                     "wall_thickness"):
            positive(f"LotConfig.{name}", getattr(self, name))
        require(math.isfinite(self.margin) and self.margin >= 0, "LotConfig.margin",
                 "a finite number >= 0", self.margin)
        for name in ("upper_slots", "left_slots", "middle_slots", "right_slots"):
            n = getattr(self, name)
            require(1 <= n <= 100, f"LotConfig.{name}", "an int in [1, 100]", n)
        require(self.middle_slots % 2 == 0, "LotConfig.middle_slots", "even", self.middle_slots)
        require(
            self.car_width < self.slot_width and self.car_length < self.slot_length,
            "LotConfig.car_width/car_length", "smaller than the slot",
            (self.car_width, self.car_length),
        )
        # Upper bounds on the sizes that set tensor shapes: a typo must not allocate the
        # machine's memory (each is far above what the task uses).
        require(0 <= self.start_candidates <= 1024, "LotConfig.start_candidates",
                 "an int in [0, 1024]", self.start_candidates)
        require(1 <= self.start_pool_size <= 2**20, "LotConfig.start_pool_size",
                 "an int in [1, 2**20]", self.start_pool_size)
        check_seed(self.pool_seed, "LotConfig.pool_seed")

    @property
    def thinnest_obstacle(self) -> float:
        """The thickness of the thinnest obstacle in metres, min(wall_thickness, car_width) (a
        parked car is narrower than it is long)."""
        return min(self.wall_thickness, self.car_width)

    @property
    def num_slots(self) -> int:
        """The lot's slots S, every row's."""
        return self.upper_slots + self.left_slots + self.middle_slots + self.right_slots


@dataclass(frozen=True)
class LidarConfig:
    """Planar LIDAR from the vehicle box centre, rays at psi + 2 pi k / n_rays."""

    n_rays: int = 16
    max_range: float = 20.0  # the paper gives none

    def __post_init__(self) -> None:
        check_types(self)
        require(1 <= self.n_rays <= 1024, "LidarConfig.n_rays", "an int in [1, 1024]",
                 self.n_rays)
        positive("LidarConfig.max_range", self.max_range)


@dataclass(frozen=True)
class RewardConfig:
    """Table 1 of the paper: r = (1 - cbrt(C)) + R_collision + R_success."""

    w_x: float = 0.35
    w_y: float = 0.35
    w_alpha: float = 0.20
    w_v: float = 0.10
    collision_penalty: float = -200.0
    success_bonus: float = 1000.0
    success_threshold: float = 4e-4

    def __post_init__(self) -> None:
        check_types(self)
        # Position and heading weights > 0: with any of them 0, C < threshold holds away from
        # the goal (all 0: every start is a success).
        for name in ("w_x", "w_y", "w_alpha"):
            positive(f"RewardConfig.{name}", getattr(self, name))
        require(math.isfinite(self.w_v) and self.w_v >= 0, "RewardConfig.w_v",
                 "a finite number >= 0", self.w_v)
        for name in ("collision_penalty", "success_bonus"):
            value = getattr(self, name)
            require(math.isfinite(value), f"RewardConfig.{name}", "finite", value)
        positive("RewardConfig.success_threshold", self.success_threshold)


_MAX_STEPS_LIMIT = 10**9  # far beyond any episode; the step counter is int64
MAX_COLLISION_SUBSTEPS = 64  # collision tests per step of dt: 64 misses no contact deeper than 8 mm


@dataclass(frozen=True)
class ParkingConfig:
    """The paper's parking task, and nothing else: the simulator (``torchpark.sim``) is built
    from this alone. The agent-side aids are a separate :class:`~torchpark.aids.config.AidsConfig`
    given to :class:`~torchpark.ParkingEnv` beside it."""

    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    lot: LotConfig = field(default_factory=LotConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    max_steps: int = 1000  # truncation, in steps of vehicle.dt
    occupancy: float = 0.0  # initial obstacle occupancy in [0, 1]
    # Poses tested for collision per step of dt, evenly spaced along the step's motion and
    # ending at its end pose: 1 is the paper's test of the end pose alone; K > 1 also catches
    # a car that touches a parked car only between two end poses (a corner through a
    # corner), missing no contact deeper than collision_miss_depth.
    collision_substeps: int = 1

    def __post_init__(self) -> None:
        check_types(self)
        require(1 <= self.max_steps <= _MAX_STEPS_LIMIT, "ParkingConfig.max_steps",
                 f"an int in [1, {_MAX_STEPS_LIMIT}]", self.max_steps)
        # A car that moves further in one step than the thinnest obstacle is thick could
        # pass through it between two collision tests.
        stride, thinnest = self.vehicle.max_speed * self.vehicle.dt, self.lot.thinnest_obstacle
        require(stride < thinnest, "VehicleConfig.max_speed * dt",
                 f"< the thinnest obstacle, min(LotConfig.wall_thickness, car_width) = "
                 f"{thinnest} m (else the car can pass through it in one step)", stride)
        check_occupancy(self.occupancy, "ParkingConfig.occupancy")
        require(1 <= self.collision_substeps <= MAX_COLLISION_SUBSTEPS,
                "ParkingConfig.collision_substeps", f"an int in [1, {MAX_COLLISION_SUBSTEPS}]",
                self.collision_substeps)

    @property
    def collision_miss_depth(self) -> float:
        """The deepest overlap with an obstacle, metres, that the collision test can miss in
        a step of dt: half the farthest any point of the car's box can travel between two
        tested poses (at full speed and full steer; the step's start pose was tested clear).
        The paper's end-pose test (collision_substeps = 1) misses up to 0.54 m for the
        paper's car; 8 sub-steps up to 67 mm."""
        car = self.vehicle
        reach = math.hypot(max(car.length - car.rear_overhang, car.rear_overhang),
                           car.width / 2.0)  # the box corner farthest from the rear axle
        stride = car.max_speed * car.dt
        turn = stride * math.tan(car.max_steer) / car.wheelbase
        return (stride + turn * reach) / (2.0 * self.collision_substeps)


def check_occupancy(value: float, name: str = "occupancy") -> float:
    """Return ``value`` as a float, or raise naming ``name`` when it is not in [0, 1]."""
    require(is_number(value) and 0.0 <= value <= 1.0, name, "a number in [0, 1]", value)
    return float(value)
