"""A route planner for the approach: the cost-to-go to each slot's docking funnel over a grid
of rear-axle poses, and the control that descends it.

The lot's geometry is the same in every env and a parked car lies inside its slot, so a
path whose car box overlaps no slot but the goal's and no wall is clear of the parked cars
at every occupancy. :func:`cost_to_go` computes, once per lot, the cost of the cheapest
path from every cell of an (x, y, heading) grid to the cells where the car is lined up
behind each slot (the target: ``reach_min`` to ``reach`` m back along the slot axis, within
``lateral`` m and ``heading`` rad of it), by value iteration over arcs of ``step`` m at a
few steering angles forwards and in reverse (reversing costs ``reverse_cost`` per metre,
``band_cost`` times as much within ``margin`` m of a slot or wall, ``slot_cost`` times as
much onto another slot; walls are never crossed): a car-like vehicle's multi-point turns
come out of it, and so does the way out of a slot the car stands in; the gear is part of
the state (a table per gear), each change of gear costing ``switch_cost`` m. Every step of
dt :func:`plan_control` tries every sequence of two arcs of ``control_step`` m from the
car's exact pose, checks their ends exactly against the slots and walls, reads the
cost-to-go of the second arc's gear at its end between cells (:func:`interpolated_cost`),
and drives the first arc of the cheapest (arcs shorter than the tables': the car finishes
a leg of a multi-point turn in a lane barely longer than itself, where arcs of ``step`` m
from its exact pose all end on a slot and it would rock between gears):
the docking law (:mod:`torchpark.aids.docking`), with its funnel set to the planner's
target, takes over from there. Everything is batched tensor ops: the tables over every
slot at once, the control over every env (the sweeps' loop is over sweeps and arcs).
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING, NamedTuple

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.envs import EnvBase

from torchpark.aids.brake import fence
from torchpark.aids.docking import error_from_goal
from torchpark.config import LotConfig, VehicleConfig
from torchpark.experts.config import ExpertConfig, PlannerConfig
from torchpark.memory import check_fits
from torchpark.sim.geometry import OrientedBoxes, oriented_boxes, separation, wrap_angle
from torchpark.sim.layout import LotLayout, build_layout
from torchpark.sim.state import ParkingState
from torchpark.sim.vehicle import gear_travel, vehicle_obb
from torchpark.sim.world import World, touches_obstacle

if TYPE_CHECKING:
    from torchpark.env import ParkingEnv


class Grid(NamedTuple):
    """The pose grid: ``size_x`` x ``size_y`` positions ``cell`` m apart from (0, 0) and
    ``headings`` angles 2 pi / headings apart from -pi; flat index ((h X) + x) Y + y."""

    cell: float
    size_x: int
    size_y: int
    headings: int

    @property
    def cells(self) -> int:
        return self.headings * self.size_x * self.size_y


def grid_of(layout: LotLayout, cfg: PlannerConfig) -> Grid:
    """The grid covering the lot rectangle at ``cfg.cell`` m and ``cfg.headings`` angles."""
    return Grid(cfg.cell, math.floor(layout.width / cfg.cell) + 1,
                math.floor(layout.height / cfg.cell) + 1, cfg.headings)


def grid_poses(grid: Grid, device: torch.device | str) -> Tensor:
    """The rear-axle pose (x m, y m, psi rad) of every cell, (count, 3), in flat order."""
    h, x, y = torch.meshgrid(torch.arange(grid.headings, device=device),
                             torch.arange(grid.size_x, device=device),
                             torch.arange(grid.size_y, device=device), indexing="ij")
    psi = wrap_angle(h.float() * (2.0 * math.pi / grid.headings) - math.pi)
    return torch.stack((x.float() * grid.cell, y.float() * grid.cell, psi), -1).reshape(-1, 3)


def _grid_coordinates(pose: Tensor, grid: Grid) -> tuple[Tensor, Tensor, Tensor]:
    """Poses [..., 3] in cell units along x, y and heading (fractional), each [...]."""
    return (pose[..., 0] / grid.cell, pose[..., 1] / grid.cell,
            (pose[..., 2] + math.pi) * (grid.headings / (2.0 * math.pi)))


def cell_index(pose: Tensor, grid: Grid) -> Tensor:
    """The flat index of the nearest cell to poses [..., 3], int64 [...]; -1 off the grid."""
    ix, iy, ih = (torch.round(c).long() for c in _grid_coordinates(pose, grid))
    ih = ih.remainder(grid.headings)
    inside = (ix >= 0) & (ix < grid.size_x) & (iy >= 0) & (iy < grid.size_y)
    return torch.where(inside, (ih * grid.size_x + ix) * grid.size_y + iy, -1)


def arcs(pose: Tensor, travel: Tensor, curvature: Tensor) -> Tensor:
    """Rear-axle poses [..., K, 3] after ``travel`` (K,) m of path (< 0: reversing) at
    ``curvature`` (K,) 1/m from poses [..., 3]: exact circular arcs of the bicycle."""
    x, y, psi = (t[..., None] for t in pose.unbind(-1))
    turn = travel * curvature
    straight = curvature.abs() < 1e-9
    k = torch.where(straight, 1.0, curvature)
    end = psi + turn
    dx = torch.where(straight, travel * torch.cos(psi), (torch.sin(end) - torch.sin(psi)) / k)
    dy = torch.where(straight, travel * torch.sin(psi), (torch.cos(psi) - torch.cos(end)) / k)
    return torch.stack((x + dx, y + dy, wrap_angle(end)), -1)


class Primitives(NamedTuple):
    """The planner's arcs, fields (K,): ``travel`` m (signed by gear), ``steer`` rad,
    ``curvature`` 1/m, ``cost`` m-equivalent."""

    travel: Tensor
    steer: Tensor
    curvature: Tensor
    cost: Tensor


def primitives(cfg: PlannerConfig, vehicle: VehicleConfig, device: torch.device | str,
               step: float | None = None) -> Primitives:
    """Arcs of ``step`` m (None: ``cfg.step``) at ``cfg.steers`` steering angles over the
    vehicle's range, forwards and reversing."""
    step = cfg.step if step is None else step
    steer = torch.linspace(-vehicle.max_steer, vehicle.max_steer, cfg.steers, device=device)
    gear = torch.tensor([1.0, -1.0], device=device).repeat_interleave(cfg.steers)
    steer = steer.repeat(2)
    cost = torch.where(gear > 0, 1.0, cfg.reverse_cost) * step
    return Primitives(gear * step, steer, torch.tan(steer) / vehicle.wheelbase, cost)


def free_cells(poses: Tensor, layout: LotLayout, vehicle: VehicleConfig, margin: float,
               chunk: int = 16384) -> tuple[Tensor, Tensor]:
    """Whether the car box at each pose (C, 3), grown by ``margin`` m, is clear of the
    walls and of every slot but the goal's, bool (S, C) (row s for goal slot s), and whether
    it is clear of the walls, bool (C,)."""
    slots = oriented_boxes(layout.slots)
    walls = oriented_boxes(layout.walls)
    rows, walled = [], []
    for part in poses.split(chunk):
        ego = fence(part, vehicle, margin)
        ego = OrientedBoxes(*(t[:, None] for t in ego))
        in_slot = separation(ego, slots) <= 0.0  # (c, S)
        count = in_slot.sum(-1, keepdim=True)
        clear = (separation(ego, walls) > 0.0).all(-1)
        rows.append(clear[:, None] & ((count == 0) | ((count == 1) & in_slot)))
        walled.append(clear)
    return torch.cat(rows).T.contiguous(), torch.cat(walled)


def target_cells(poses: Tensor, layout: LotLayout, cfg: PlannerConfig) -> Tensor:
    """Whether each pose (C, 3) is lined up behind each slot: bool (S, C)."""
    error = error_from_goal(poses[None], layout.goal_poses[:, None])
    return ((error.remaining >= cfg.reach_min) & (error.remaining <= cfg.reach)
            & (error.lateral.abs() <= cfg.lateral) & (error.heading.abs() <= cfg.heading))


def cost_to_go(layout: LotLayout, vehicle: VehicleConfig, cfg: PlannerConfig,
               max_sweeps: int = 10_000) -> Tensor:
    """The cheapest path's cost from every cell to each slot's target, float32 (S, 2, count):
    ``[:, 0]`` for a car moving forwards, ``[:, 1]`` for one reversing, each path paying
    ``switch_cost`` m for every change of gear along it, the first against the car's (inf
    where none is found, as from cells on a wall): value iteration until no cell changes.
    The tables price a path's changes of gear as :func:`plan_control` does its own."""
    device = layout.slots.device
    grid = grid_of(layout, cfg)
    prim = primitives(cfg, vehicle, device)
    slots, arcs_k = layout.num_slots, prim.travel.shape[0]
    # per cell, the tables and the arcs' costs (S, per arc and gear), the arcs' end cells,
    # the slot tests' temporaries: 3.6 KB for the paper's lot, as measured (peak RSS)
    check_fits(grid.cells * (slots * (59 + 4 * arcs_k) + 16 * arcs_k + 12),
               f"PlannerConfig(cell={cfg.cell:g}, headings={cfg.headings}): its grid of "
               f"{grid.cells:,} cells", torch.device(device))
    poses = grid_poses(grid, device)
    ends = cell_index(arcs(poses, prim.travel, prim.curvature), grid)  # (C, K)
    mids = cell_index(arcs(poses, prim.travel / 2, prim.curvature), grid)
    free, walled = free_cells(poses, layout, vehicle, cfg.clearance)  # (S, C), (C,)
    roomy, _ = free_cells(poses, layout, vehicle, cfg.margin)
    # index -1: off the grid
    on_slot = torch.cat((~free, torch.ones_like(free[:, :1])), 1)
    on_wall = torch.cat((~walled, walled.new_ones(1)))
    inf = torch.tensor(math.inf, device=device)
    value = torch.where(target_cells(poses, layout, cfg) & roomy, 0.0, inf)
    value = torch.cat((value, torch.full_like(value[:, :1], math.inf)), 1)
    value = torch.stack((value, value), 1)  # (S, 2, C + 1): forwards, reversing
    # The cost of each arc from each cell (S, C): inf where it ends or passes off the grid
    # or on a wall, ``slot_cost`` times more where it ends or passes on another slot,
    # ``band_cost`` times more where it ends within the margin of a slot or wall.
    arc_cost = []
    for k in range(ends.shape[1]):
        end, mid = ends[:, k], mids[:, k]
        scale = torch.where(on_slot[:, end] | on_slot[:, mid], cfg.slot_cost,
                            torch.where(roomy[:, end.clamp(min=0)], 1.0, cfg.band_cost))
        arc_cost.append(torch.where(on_wall[end] | on_wall[mid], inf, prim.cost[k] * scale))
    reversing = (prim.travel < 0).long().tolist()
    for _ in range(max_sweeps):
        # the cheapest path that starts with an arc forwards, and one reversing
        start = [value.new_full(value[:, 0, :-1].shape, math.inf) for _ in range(2)]
        for k, cost in enumerate(arc_cost):
            g = reversing[k]
            start[g] = torch.minimum(start[g], value[:, g, ends[:, k]] + cost)
        best = torch.stack((torch.minimum(start[0], start[1] + cfg.switch_cost),
                            torch.minimum(start[1], start[0] + cfg.switch_cost)), 1)
        best = torch.where(walled, torch.minimum(value[:, :, :-1], best), inf)
        if torch.equal(best, value[:, :, :-1]):
            break
        value = torch.cat((best, value[:, :, -1:]), 2)
    return value[:, :, :-1].contiguous()


class Planner(NamedTuple):
    """A lot's cost-to-go tables (:func:`cost_to_go`) with what reading them needs: the
    slots (S,) and walls (4,) its paths keep off, and the vehicle."""

    value: Tensor  # (S, 2, count) float32: forwards, reversing
    grid: Grid
    prim: Primitives  # the tables' arcs, ``cfg.step`` m
    control: Primitives  # the control's, ``cfg.control_step`` m
    slots: OrientedBoxes
    walls: OrientedBoxes
    vehicle: VehicleConfig
    cfg: PlannerConfig


def build_planner(layout: LotLayout, vehicle: VehicleConfig, cfg: PlannerConfig) -> Planner:
    """The planner of a lot (its tables take a few seconds to two minutes to compute)."""
    device = layout.slots.device
    return Planner(cost_to_go(layout, vehicle, cfg), grid_of(layout, cfg),
                   primitives(cfg, vehicle, device),
                   primitives(cfg, vehicle, device, cfg.control_step), oriented_boxes(layout.slots),
                   oriented_boxes(layout.walls), vehicle, cfg)


def clear_of_slots(planner: Planner, pose: Tensor, goal_slot: Tensor) -> tuple[Tensor, Tensor]:
    """Whether the car box at poses (N, M, 3) is clear of every slot but ``goal_slot``
    (N,)'s, and whether it is clear of the walls, bool (N, M) each: exactly, not on the
    grid."""
    ego = vehicle_obb(pose, planner.vehicle)
    ego = OrientedBoxes(*(t[..., None] for t in ego))
    other = torch.arange(planner.slots.cx.shape[0], device=pose.device) != goal_slot[:, None]
    in_other = (separation(ego, planner.slots) <= 0.0) & other[:, None, :]
    return ~in_other.any(-1), (separation(ego, planner.walls) > 0.0).all(-1)


UNREACHABLE = 1e6  # m: the cost read where no surrounding cell has a path


def interpolated_cost(value: Tensor, row: Tensor, pose: Tensor, grid: Grid,
                      blocked_cost: float) -> Tensor:
    """Rows ``row`` (N, K) of the cost-to-go tables ``value`` (R, count) read at poses
    (N, K, 3), (N, K): linear in x, y and heading between the 8 surrounding cells, a cell no
    path leaves (or off the grid) counting as the dearest of the others plus
    ``blocked_cost`` m, so the cost rises towards obstacles; UNREACHABLE m where no
    surrounding cell has a path."""
    fx, fy, fh = _grid_coordinates(pose, grid)
    x0, y0, h0 = fx.floor(), fy.floor(), fh.floor()
    wx, wy, wh = fx - x0, fy - y0, fh - h0
    costs, weights = [], []
    for dx, dy, dh in ((a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)):
        ix, iy = (x0 + dx).long(), (y0 + dy).long()
        ih = (h0 + dh).long().remainder(grid.headings)
        inside = (ix >= 0) & (ix < grid.size_x) & (iy >= 0) & (iy < grid.size_y)
        index = ((ih * grid.size_x + ix.clamp(0, grid.size_x - 1)) * grid.size_y
                 + iy.clamp(0, grid.size_y - 1))
        cost = value.reshape(-1)[index + row * grid.cells]
        costs.append(torch.where(inside, cost, math.inf))
        weights.append((wx if dx else 1 - wx) * (wy if dy else 1 - wy) * (wh if dh else 1 - wh))
    cost, weight = torch.stack(costs, -1), torch.stack(weights, -1)
    finite = cost.isfinite()
    dearest = torch.where(finite, cost, -math.inf).amax(-1, keepdim=True)
    cost = torch.where(finite, cost, dearest + blocked_cost)
    return torch.where(finite.any(-1), (weight * cost).sum(-1), UNREACHABLE)


def near_cars(planner: Planner, pose: Tensor, cars: tuple[World, Tensor]) -> Tensor:
    """Whether the car box at poses (N, J, 3), grown by ``cfg.car_margin`` m
    (:func:`~torchpark.aids.brake.fence`), touches a present obstacle (``cars``: the world
    and its (N, M) present mask), bool (N, J)."""
    world, present = cars
    return touches_obstacle(fence(pose, planner.vehicle, planner.cfg.car_margin), world,
                            present[:, None, :])


def plan_control(planner: Planner, pose: Tensor, speed: Tensor, goal_slot: Tensor,
                 keep_gear: Tensor | None = None, cars: tuple[World, Tensor] | None = None
                 ) -> tuple[Tensor, Tensor, Tensor]:
    """The planner's control at poses (N, 3) moving at ``speed`` (N,) m/s towards slots
    ``goal_slot`` (N,): (v m/s, delta rad, cost-to-go m), each (N,). Of the sequences of
    two arcs of ``cfg.control_step`` m from the exact pose, the one whose end has the least
    cost in its second arc's gear (:func:`interpolated_cost`) plus the arcs' own
    (``slot_cost`` times theirs where an arc's end puts the car on another slot,
    :func:`clear_of_slots`; plus ``switch_cost`` for each change of gear, the first against
    the way the car moves), among those whose two ends keep the car off the walls, gives
    the first arc's gear and steering; v is ``speed`` in that gear, 0 where every sequence
    is blocked or ends among cells no path leaves. Rows of ``keep_gear`` (N,) bool
    (:class:`GearHold`) choose among the sequences whose first arc is in the gear the car
    moves in, where one of them is open. With ``cars`` (the env's world and (N, M) present
    obstacles) and ``cfg.car_margin`` > 0, a sequence either of whose arcs ends with the car
    box grown by the margin on an obstacle it was clear of before (:func:`near_cars`) is
    blocked, as a wall's is."""
    prim, cfg = planner.control, planner.cfg
    gear = torch.sign(prim.travel)
    first = arcs(pose, prim.travel, prim.curvature)  # (N, K, 3)
    second = arcs(first, prim.travel, prim.curvature)  # (N, K, K, 3)
    n, k = first.shape[:2]
    # the table of the second arc's gear
    row = goal_slot[:, None, None] * 2 + (gear < 0).long()
    ahead = interpolated_cost(planner.value.flatten(0, 1), row.expand(n, k, k).reshape(n, -1),
                              second.reshape(n, k * k, 3), planner.grid,
                              cfg.blocked_cost).view(n, k, k)
    moving = torch.sign(speed)[:, None]
    switch = torch.where((moving != 0) & (moving != gear), cfg.switch_cost, 0.0)  # (N, K)
    again = torch.where(gear[:, None] != gear[None, :], cfg.switch_cost, 0.0)  # (K, K)
    off_first, walled_first = clear_of_slots(planner, first, goal_slot)  # (N, K)
    off_second, walled_second = (c.view(n, k, k) for c in clear_of_slots(
        planner, second.reshape(n, k * k, 3), goal_slot))
    own_first = prim.cost * torch.where(off_first, 1.0, cfg.slot_cost)  # (N, K)
    own_second = prim.cost * torch.where(off_second, 1.0, cfg.slot_cost)  # (N, K, K)
    total = ahead + again + own_second + (own_first + switch)[:, :, None]
    open_ = walled_first[:, :, None] & walled_second
    if cars is not None and cfg.car_margin > 0:
        near_now = near_cars(planner, pose[:, None], cars)  # (N, 1)
        near_first = near_cars(planner, first, cars) & ~near_now  # (N, K)
        near_second = near_cars(planner, second.reshape(n, k * k, 3), cars).view(n, k, k)
        open_ = open_ & ~near_first[:, :, None] & ~(
            near_second & ~(near_first | near_now)[:, :, None])
    total = torch.where(open_, total, math.inf)
    if keep_gear is not None:
        kept = torch.where(((gear == moving) | (moving == 0))[:, :, None], total, math.inf)
        open_kept = kept.flatten(1).amin(-1) < 0.5 * UNREACHABLE
        total = torch.where((keep_gear & open_kept)[:, None, None], kept, total)
    best, index = total.flatten(1).min(-1)
    index = index // k
    reachable = best < 0.5 * UNREACHABLE  # also False where every sequence is blocked
    v = torch.where(reachable, gear[index] * cfg.speed, 0.0)
    return v, prim.steer[index], best


class GearHold:
    """The planner's commitment to a change of gear (``PlannerConfig.gear_hold``): per env,
    the car's gear (the sign of its speed) and its travel since it last changed, m. A row
    keeps its gear (``plan_control(..., keep_gear)``) until it has travelled ``distance`` m
    in it. The greedy control alone reads the tables between cells while the exact checks
    refuse some of their moves, and at a lane's edge it can go two steps forwards and two
    back for ever (research/experiments.md); a held gear leaves such a cycle.

    It follows the car, not the commands: what another driver (a student under DAgger) or
    the brake did counts."""

    def __init__(self, distance: float, num_envs: int, device: torch.device | str) -> None:
        self.distance = distance
        self.gear = torch.zeros(num_envs, device=device)
        self.travel = torch.full((num_envs,), math.inf, device=device)

    def keep(self, speed: Tensor, fresh: Tensor, step_time: float) -> Tensor:
        """The rows (N,) bool to keep their gear, given each car's ``speed`` (N,) m/s over
        the last step of ``step_time`` s and ``fresh`` (N,) bool, the rows whose episode has
        just begun (no step taken)."""
        gear, travel = gear_travel(speed, self.gear, self.travel, step_time)
        self.travel = torch.where(fresh, math.inf, travel)
        self.gear = torch.where(fresh, 0.0, gear)
        return self.travel < self.distance

    def keep_in(self, state: ParkingState, env: ParkingEnv) -> Tensor | None:
        """:meth:`keep` for the cars in ``state``, ``env``'s (a ParkingEnv, stepping
        ``action_repeat`` steps of dt per action) before its next action; None when there is
        no hold (``distance`` 0: ``plan_control``'s greedy choice)."""
        if self.distance == 0:
            return None
        return self.keep(state.speed, state.steps == 0,
                         env.config.vehicle.dt * env.action_repeat)


@functools.lru_cache(maxsize=4)
def lot_planner(lot: LotConfig, vehicle: VehicleConfig, cfg: PlannerConfig, device: str
                ) -> Planner:
    """The planner of the lot, built on first use and kept for the process (the lot's
    geometry is the same in every env, so one set of tables serves every env and every
    occupancy)."""
    return build_planner(build_layout(lot, vehicle, device), vehicle, cfg)


class PlannerExpert:
    """The hand-written agent as a policy: ``expert(td)`` writes into ``td["action"]``
    (N, 2) the approach planner's control (v m/s, delta rad) for ``env``'s cars (it reads
    their pose, speed and goal slot from the env's state, as a car that knows the lot's map
    and its place in it would). ``env`` must be built with ``config.aids()``: the docking law
    there takes over in its funnel and the brake stops or steers what would touch, as for a
    checkpoint's policy."""

    def __init__(self, env: EnvBase, config: ExpertConfig | None = None) -> None:
        self.config = config if config is not None else ExpertConfig()
        base = getattr(env, "base_env", env)
        if base.aids != self.config.aids():
            raise ValueError(f"env must be built with the expert's aids "
                             f"(aids=ExpertConfig.aids() = {self.config.aids()}), got "
                             f"{base.aids}")
        self.env = base
        self.planner = lot_planner(base.config.lot, base.config.vehicle, self.config.planner,
                                   str(base.device))
        self.hold = GearHold(self.config.planner.gear_hold, base.num_envs, base.device)

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        state = self.env.state
        v, delta, _ = plan_control(self.planner, state.pose, state.speed, state.goal_slot,
                                   self.hold.keep_in(state, self.env),
                                   (self.env.world, state.present))
        return td.set("action", torch.stack((v, delta), -1))
