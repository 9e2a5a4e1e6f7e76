"""Configuration of the agent-side aids: layers between a policy and the paper's simulator,
each off unless asked for. ``AidsConfig()`` changes nothing; ``ParkingEnv(config, aids=None)``
is the paper's task. Units: metres, seconds, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from torchpark.config import check_types, positive, require


@dataclass(frozen=True)
class BrakeConfig:
    """An emergency brake under the policy (the paper has none; its "future work" names one):
    a step of dt whose new pose would touch a parked car or a wall is not taken, the car
    stays where it is with speed 0, so no collision can happen.

    steer_clear: 0, the brake stops such a step; k >= 2, it first tries k steering angles
    evenly spread over the vehicle's range at the commanded speed and takes the step with the
    clear one nearest the commanded angle, stopping only when none is clear.
    penalty: added to the reward of a step the brake stops or steers (a training signal
    against leaning on it; 0 by default).
    margin: m; > 0, the brake also acts on a step that would bring the car's box, grown by
    ``margin`` on every side, onto an obstacle it was clear of at the step's start: the car
    keeps that much room (a pose that starts closer keeps the exact test). 0: the exact test.
    """

    steer_clear: int = 0
    penalty: float = 0.0
    margin: float = 0.0  # m

    def __post_init__(self) -> None:
        check_types(self)
        require(self.steer_clear == 0 or 2 <= self.steer_clear <= 1024,
                "BrakeConfig.steer_clear", "0 or an int in [2, 1024]", self.steer_clear)
        require(math.isfinite(self.penalty), "BrakeConfig.penalty", "finite", self.penalty)
        require(math.isfinite(self.margin) and 0.0 <= self.margin <= 1.0, "BrakeConfig.margin",
                "in [0, 1] m", self.margin)


@dataclass(frozen=True)
class NearGoalStarts:
    """Training starts near the goal (the paper's starts are uniform over the lot): with
    probability ``probability`` a reset's start is drawn near the goal instead, the rear axle
    up to ``reach`` m back along the slot axis from the goal pose, up to ``lateral`` m to
    either side and ``heading`` rad off the slot heading; ``candidates`` such poses are tried
    (the first inside the lot that touches no parked car or wall and does not already meet
    the success test is taken), and the uniform start is kept when none fits."""

    probability: float = 0.5
    reach: float = 6.0
    lateral: float = 1.0
    heading: float = 0.6
    candidates: int = 8

    def __post_init__(self) -> None:
        check_types(self)
        require(0.0 <= self.probability <= 1.0, "NearGoalStarts.probability", "in [0, 1]",
                self.probability)
        for name in ("reach", "lateral", "heading"):
            value = getattr(self, name)
            require(math.isfinite(value) and value >= 0, f"NearGoalStarts.{name}",
                    "finite, >= 0", value)
        require(1 <= self.candidates <= 1024, "NearGoalStarts.candidates",
                "an int in [1, 1024]", self.candidates)


@dataclass(frozen=True)
class DockingConfig:
    """The docking law (:mod:`torchpark.aids.docking`): once the rear axle is in the
    funnel around its slot's approach (0 to ``reach`` m back along the slot axis from the
    goal, within ``lateral`` m of it, heading within ``heading`` rad of the goal's), a fixed
    feedback law drives for the rest of the episode: tan(delta) = L (-k e -+ 2 sqrt(k) th) for
    lateral offset e and heading error th (- forwards, + reversing; critically damped over
    1 / sqrt(k) m travelled either way), k = ``gain`` once settled (within
    ``settled_lateral`` m and ``settled_heading`` rad), else ``forward_gain`` /
    ``reverse_gain``. Settled, it drives in at v = clamp(speed_gain s, min_speed, max_speed),
    s m from the goal; otherwise at max_speed. It reverses when the emergency brake
    (``AidsConfig.brake``) stops it, when past the goal, or when less than ``abort`` m from
    the goal without being settled, and drives forwards again when braked or ``run_in`` m
    back. Settled within ``settle`` m of the goal, either side, it creeps to the goal at
    clamp(speed_gain |s|, min_speed, max_speed), reversing where past it, whatever its pass
    (0, the default: past the goal, it reverses a whole pass). With ``retry`` > 0 it creeps
    back from past the goal only within ``finish_lateral`` m and ``finish_heading`` rad of
    the axis, where the success test can still pass (0.35 * 3e-4 + 0.2 * 6e-4 of its 4e-4,
    the rest for the creep's mm/s); beyond, it reverses a pass that ends, settled, ``retry`` m
    back, and drives in again (a creep at the goal cannot move the car sideways).
    """

    reach: float = 8.0  # m
    lateral: float = 4.0  # m
    heading: float = math.pi  # rad: any heading
    gain: float = 16.0  # 1/m^2
    forward_gain: float = 0.25  # 1/m^2
    reverse_gain: float = 0.125  # 1/m^2
    settled_lateral: float = 0.1  # m
    settled_heading: float = 0.1  # rad
    speed_gain: float = 0.8  # 1/s
    min_speed: float = 1e-3  # m/s: the success test needs |v| well under 4 mm/s
    max_speed: float = 1.0  # m/s
    abort: float = 0.5  # m
    # m: reversing, in practice until the brake stops it; settled, the law brings the errors
    # to ~1e-5 within ~4 m of path
    run_in: float = 10.0
    settle: float = 0.0  # m
    retry: float = 0.0  # m
    finish_lateral: float = 3e-4  # m
    finish_heading: float = 6e-4  # rad

    def __post_init__(self) -> None:
        check_types(self)
        for name in ("reach", "lateral", "heading", "gain", "forward_gain", "reverse_gain",
                     "settled_lateral", "settled_heading", "speed_gain", "min_speed",
                     "max_speed", "run_in", "finish_lateral", "finish_heading"):
            positive(f"DockingConfig.{name}", getattr(self, name))
        require(math.isfinite(self.abort) and 0.0 <= self.abort <= self.run_in,
                 "DockingConfig.abort", f"in [0, run_in = {self.run_in}]", self.abort)
        require(self.min_speed <= self.max_speed, "DockingConfig.min_speed",
                 f"<= max_speed = {self.max_speed}", self.min_speed)
        require(math.isfinite(self.settle) and 0.0 <= self.settle <= self.abort,
                "DockingConfig.settle", f"in [0, abort = {self.abort}]", self.settle)
        require(math.isfinite(self.retry) and 0.0 <= self.retry <= self.run_in,
                "DockingConfig.retry", f"in [0, run_in = {self.run_in}]", self.retry)


@dataclass(frozen=True)
class AidsConfig:
    """The aids an agent is made of, each off unless set.

    action_repeat: steps of dt one action is held for (1: a new action every 0.1 s, as the
    paper). With k > 1 one env step advances up to k steps of dt, stops early at the one that
    ends the episode, and returns the sum of their rewards (:mod:`torchpark.aids.repeat`).
    brake: the emergency brake (:mod:`torchpark.aids.brake`). docking: the docking law
    (:mod:`torchpark.aids.docking`), which turns around when the brake stops it.
    near_goal_starts: training starts near the goal (:mod:`torchpark.aids.starts`).
    observe_position: the env also emits ``"position"``, the rear axle's (x, y) in the lot
    (m; the paper's observation has only the goal's offset from it), for a policy whose
    route depends on where in the lot it is (a car localised on a map of the lot).
    """

    action_repeat: int = 1
    brake: BrakeConfig | None = None
    docking: DockingConfig | None = None
    near_goal_starts: NearGoalStarts | None = None
    observe_position: bool = False

    def __post_init__(self) -> None:
        check_types(self)
        require(1 <= self.action_repeat <= 1000, "AidsConfig.action_repeat",
                "an int in [1, 1000]", self.action_repeat)
