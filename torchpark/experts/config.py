"""Configuration of the hand-written experts: the approach planner
(:mod:`torchpark.experts.planner`), the agent it drives with (:class:`ExpertConfig`) and the
distiller's teacher, the same parts composed outside the env (:class:`TeacherConfig`).
Units: metres, seconds, radians."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from torchpark.aids.config import AidsConfig, BrakeConfig, DockingConfig
from torchpark.config import check_types, positive, require


@dataclass(frozen=True)
class PlannerConfig:
    """The approach planner (:mod:`torchpark.experts.planner`): a cost-to-go over a grid of
    rear-axle poses ``cell`` m and 2 pi / ``headings`` rad apart, by arcs of ``step`` m at
    ``steers`` steering angles, forwards and reversing (``reverse_cost`` per metre). On the
    grid the car box, grown by ``clearance`` m, keeps off the walls, and a path costs
    ``slot_cost`` times as much per metre where it is on a slot but the goal's (inf: it
    never is; finite: a car standing on one drives off it), ``band_cost`` times as much
    within ``margin`` m of a slot or wall. Its target: ``reach_min`` to ``reach`` m back along
    the slot axis from the goal, within ``lateral`` m and ``heading`` rad of it. It drives at
    ``speed`` m/s, looking ahead two arcs of ``control_step`` m; a gear change costs
    ``switch_cost`` m; reading the cost between cells, one no path leaves counts
    ``blocked_cost`` m dearer than the others; with ``car_margin`` m > 0 its exact checks
    also refuse an arc whose end brings the car box, grown by that much, onto a parked car or
    a wall it was clear of before the arc (the tables know slots, not which hold a car: this
    keeps the control off the cars it would otherwise only graze past, which the brake
    stops). After the car changes gear it keeps the new
    one for ``gear_hold`` m of travel wherever a look-ahead in it is open (0: the greedy
    choice at every step, which can cycle forwards and back at a lane's edge; see
    :class:`~torchpark.experts.planner.GearHold`). The docking law takes over from it within
    ``law_reach`` m behind the goal, ``law_lateral`` m of the slot axis and ``law_heading``
    rad of the goal's heading (:meth:`law_funnel`; None: the target's bound); a funnel
    wider than the target hands over to the law where the planner's arcs would circle a
    slot off a narrow lane (research/experiments.md)."""

    cell: float = 0.5  # m
    headings: int = 64
    step: float = 0.75  # m
    control_step: float = 0.375  # m
    steers: int = 5
    reverse_cost: float = 1.5
    switch_cost: float = 2.0  # m
    clearance: float = 0.0  # m
    margin: float = 0.2  # m
    band_cost: float = 5.0
    slot_cost: float = 1000.0
    blocked_cost: float = 10.0  # m
    speed: float = 2.0  # m/s
    reach_min: float = 3.0  # m
    reach: float = 7.0  # m
    lateral: float = 0.5  # m
    heading: float = 0.25  # rad
    law_reach: float | None = None  # m
    law_lateral: float | None = None  # m
    law_heading: float | None = None  # rad
    gear_hold: float = 0.0  # m
    car_margin: float = 0.0  # m

    def __post_init__(self) -> None:
        check_types(self)
        for name in ("cell", "step", "control_step", "speed", "reach", "lateral", "heading"):
            positive(f"PlannerConfig.{name}", getattr(self, name))
        require(self.heading <= math.pi, "PlannerConfig.heading", "in (0, pi] (rad)",
                self.heading)
        for name, high in (("reach", math.inf), ("lateral", math.inf), ("heading", math.pi)):
            value, low = getattr(self, f"law_{name}"), getattr(self, name)
            require(value is None or (low <= value <= high and math.isfinite(value)),
                    f"PlannerConfig.law_{name}", f"None or finite, in [{name} = {low:g}, "
                    f"{high:g}] (the funnel holds the target)", value)
        require(8 <= self.headings <= 1024, "PlannerConfig.headings", "an int in [8, 1024]",
                self.headings)
        require(2 <= self.steers <= 64, "PlannerConfig.steers", "an int in [2, 64]",
                self.steers)
        for name in ("reverse_cost", "switch_cost", "clearance", "margin", "band_cost",
                     "blocked_cost", "reach_min", "gear_hold", "car_margin"):
            value = getattr(self, name)
            require(math.isfinite(value) and value >= 0, f"PlannerConfig.{name}",
                    "finite, >= 0", value)
        require(self.slot_cost >= 1.0, "PlannerConfig.slot_cost", ">= 1 (inf: never on a slot)",
                self.slot_cost)
        require(self.reach_min < self.reach, "PlannerConfig.reach_min",
                f"< reach = {self.reach}", self.reach_min)

    def law_funnel(self, law: DockingConfig) -> DockingConfig:
        """``law`` with the funnel it takes over from the planner in: the ``law_*`` bounds,
        the target's where None."""
        return dataclasses.replace(law, **{
            name: getattr(self, name) if getattr(self, f"law_{name}") is None
            else getattr(self, f"law_{name}") for name in ("reach", "lateral", "heading")})


@dataclass(frozen=True)
class ExpertConfig:
    """The hand-written agent (``results/planner/``): the approach planner drives from the
    paper's uniform start until the docking law's funnel (``planner.law_*``, here 8 m behind
    the goal, 2 m of its axis and 1 rad of its heading: wider than the planner's target, so
    that the law turns in the cars the planner's arcs would circle off a narrow lane), the
    docking law (``docking``, its funnel replaced by the planner's) parks, and the emergency
    brake (``brake``, steering clear at 5 angles) stops or steers a move that would touch.
    """

    planner: PlannerConfig = field(default_factory=lambda: PlannerConfig(
        law_reach=8.0, law_lateral=2.0, law_heading=1.0))
    docking: DockingConfig = field(default_factory=DockingConfig)
    brake: BrakeConfig | None = field(default_factory=lambda: BrakeConfig(steer_clear=5))

    def __post_init__(self) -> None:
        check_types(self)

    def aids(self) -> AidsConfig:
        """The aids the expert's env is built with: its docking law and brake."""
        return AidsConfig(docking=self.planner.law_funnel(self.docking), brake=self.brake)


# The teacher's longest look-ahead before its law takes over (TeacherConfig.handover), steps
# of dt.
HANDOVER_LIMIT = 1000


@dataclass(frozen=True)
class TeacherConfig(ExpertConfig):
    """The distiller's teacher (:class:`~torchpark.experts.teacher.Teacher`): the expert's
    planner, docking law and brake, composed outside the env around a car of the paper's env
    and told apart by what a student can see (its labels are a function of the state, not of
    the episode so far). ``reverse_margin`` m: 0, or the law's reversing pass, which otherwise
    runs until the brake stops it at contact, turns forwards where the car's box moved that
    far straight back would touch a parked car or a wall (at most the lot's thinnest
    obstacle, which the teacher checks against its env's lot). ``handover`` steps of dt: 0,
    the law takes over anywhere in its funnel (``planner.law_*``); H > 0, beyond the
    planner's own target (where it always does) only where the law itself, simulated H steps
    on from there, touches nothing."""

    reverse_margin: float = 0.0  # m
    handover: int = 0  # steps of dt

    def __post_init__(self) -> None:
        super().__post_init__()
        require(math.isfinite(self.reverse_margin) and self.reverse_margin >= 0,
                "TeacherConfig.reverse_margin", "finite, >= 0 (m)", self.reverse_margin)
        require(0 <= self.handover <= HANDOVER_LIMIT, "TeacherConfig.handover",
                f"an int in [0, {HANDOVER_LIMIT}] (steps of dt)", self.handover)
