"""The approach planner (torchpark.experts.planner): exact arcs, the grid's indexing, the free
cells against a shapely oracle, paths down the cost-to-go that reach the target clear of
every slot but the goal's (or drive off the one the car stands on), and its settings refused
by name."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from tests.conftest import polygon
from torchpark import DockingConfig, ParkingConfig, ParkingEnv, VehicleConfig
from torchpark.aids.brake import fence
from torchpark.experts import ExpertConfig, PlannerConfig, PlannerExpert
from torchpark.experts.planner import (
    GearHold,
    arcs,
    build_planner,
    cell_index,
    free_cells,
    grid_of,
    grid_poses,
    plan_control,
    target_cells,
)
from torchpark.sim.vehicle import bicycle_step, vehicle_boxes
from torchpark.sim.world import touches_obstacle

# A coarse grid: its tables build in seconds on the default lot.
COARSE = PlannerConfig(cell=1.0, headings=32, step=1.5)


@pytest.fixture(scope="module")
def planner(layout, config):
    return build_planner(layout, config.vehicle, COARSE)


@pytest.mark.slow
def test_arcs_are_the_bicycle_integrated_finely():
    gen = torch.Generator().manual_seed(0)
    pose = torch.rand(64, 3, generator=gen, dtype=torch.float64) * torch.tensor(
        [40.0, 30.0, 2 * math.pi], dtype=torch.float64) - torch.tensor([0, 0, math.pi])
    travel = torch.tensor([1.5, -1.5, 0.75, -0.75, 2.0, -2.0], dtype=torch.float64)
    steer = torch.tensor([0.785, 0.785, 0.0, 0.0, -0.4, -0.4], dtype=torch.float64)
    vehicle = VehicleConfig(dt=1e-4)
    ends = arcs(pose, travel, torch.tan(steer) / vehicle.wheelbase)  # (64, 6, 3)
    # Every (pose, arc) pair integrated at once: 20,000 steps of 0.1 ms over each arc.
    x = pose[:, None].expand(64, 6, 3).reshape(-1, 3)
    speed = (travel / 1e-4 / 20_000).repeat(64)
    angle = steer.repeat(64)
    for _ in range(20_000):
        x = bicycle_step(x, speed, angle, vehicle)
    x = x.reshape(64, 6, 3)
    assert torch.allclose(ends[..., :2], x[..., :2], atol=1e-3)
    assert torch.allclose(torch.remainder(ends[..., 2] - x[..., 2] + math.pi, 2 * math.pi),
                          torch.full((64, 6), math.pi, dtype=torch.float64), atol=1e-3)


def test_cell_index_inverts_grid_poses_and_refuses_off_the_grid(layout):
    grid = grid_of(layout, COARSE)
    poses = grid_poses(grid, "cpu")
    assert torch.equal(cell_index(poses, grid), torch.arange(grid.cells))
    off = torch.tensor([[-1.0, 5.0, 0.0], [5.0, layout.height + 2 * grid.cell, 0.0]])
    assert (cell_index(off, grid) == -1).all()
    # pi and -pi are the same heading, the same cell
    assert cell_index(torch.tensor([[5.0, 5.0, math.pi]]), grid) == cell_index(
        torch.tensor([[5.0, 5.0, -math.pi]]), grid)


def test_free_cells_match_a_shapely_oracle(layout, config):
    gen = torch.Generator().manual_seed(1)
    poses = torch.rand(400, 3, generator=gen) * torch.tensor(
        [layout.width, layout.height, 2 * math.pi]) - torch.tensor([0, 0, math.pi])
    free, walled = free_cells(poses, layout, config.vehicle, 0.0)  # (S, 400), (400,)
    slots = [polygon(box) for box in layout.slots]
    walls = [polygon(box) for box in layout.walls]
    checked = 0
    for c, box in enumerate(vehicle_boxes(poses, config.vehicle)):
        car = polygon(box)
        # ill-posed within float32 rounding: a graze or a near miss of a millimetre
        if any(car.intersection(p).area < 1e-4 if car.intersects(p) else car.distance(p) < 1e-3
               for p in slots + walls):
            continue
        hit = [car.intersects(p) for p in slots]
        clear_of_walls = not any(car.intersects(w) for w in walls)
        assert bool(walled[c]) == clear_of_walls, c
        for s in range(len(slots)):
            others = any(h for j, h in enumerate(hit) if j != s)
            assert bool(free[s, c]) == (clear_of_walls and not others), (c, s)
        checked += 1
    assert checked > 350 and free.any() and not free.all()


@pytest.mark.slow
def test_paths_down_the_cost_to_go_reach_the_target_and_keep_off_the_other_slots(
        planner, layout, config):
    """From a cell clear of the other slots with a clear path (cheaper than one arc onto a
    slot) the descent stays clear of them, so of their parked cars at any occupancy; from
    a cell on one it drives off it. Each gear's table prices its changes of gear."""
    grid = planner.grid
    poses = grid_poses(grid, "cpu")
    target = target_cells(poses, layout, COARSE)
    roomy, _ = free_cells(poses, layout, config.vehicle, COARSE.margin)
    free, walled = free_cells(poses, layout, config.vehicle, COARSE.clearance)
    for gear in (0, 1):
        assert torch.equal(planner.value[:, gear] == 0, target & roomy)
    # a gear change is worth at most switch_cost, and somewhere it is worth all of it
    forwards, reversing = planner.value.unbind(1)
    finite = forwards.isfinite()
    assert torch.equal(finite, reversing.isfinite())
    gap = (forwards - reversing)[finite].abs()
    assert gap.max() <= COARSE.switch_cost + 1e-4 and (gap > 0.9 * COARSE.switch_cost).any()
    # a path to the target from (almost) every cell off the walls, where the grid has one
    has_target = (forwards == 0).any(1)
    assert has_target.sum() > 30
    assert forwards[has_target][:, walled].isfinite().float().mean() > 0.99
    assert not planner.value[:, :, ~walled].isfinite().any()
    ends = cell_index(arcs(poses, planner.prim.travel, planner.prim.curvature), grid)
    mids = cell_index(arcs(poses, planner.prim.travel / 2, planner.prim.curvature), grid)
    arc_gear = (planner.prim.travel < 0).long()
    gen = torch.Generator().manual_seed(2)
    picks = planner.value.isfinite().nonzero()
    picks = picks[torch.randint(picks.shape[0], (300,), generator=gen)]
    cars = [polygon(box) for box in layout.cars]
    onto_slot = COARSE.slot_cost * planner.prim.cost.min()
    started_on_slot = 0
    for slot, gear, cell in picks.tolist():
        value = planner.value[slot]  # (2, count)
        clear = bool(free[slot, cell]) and value[gear, cell] < onto_slot
        started_on_slot += not free[slot, cell]
        for _ in range(1000):
            if value[gear, cell] == 0:
                break
            nxt, mid = ends[cell], mids[cell]
            options = torch.where(nxt >= 0, value[arc_gear, nxt.clamp(min=0)], math.inf)
            on_slot = ~(free[slot, nxt.clamp(min=0)] & free[slot, mid.clamp(min=0)])
            scale = torch.where(on_slot, COARSE.slot_cost, torch.where(
                roomy[slot, nxt.clamp(min=0)], 1.0, COARSE.band_cost))
            step = (options + planner.prim.cost * scale
                    + torch.where(arc_gear != gear, COARSE.switch_cost, 0.0))
            assert step.min() <= value[gear, cell] + 1e-4  # the cost falls along the arc taken
            cell, gear = int(nxt[step.argmin()]), int(arc_gear[step.argmin()])
            car = polygon(vehicle_boxes(poses[cell], config.vehicle))
            on_car = any(car.intersects(p) for j, p in enumerate(cars) if j != slot)
            assert not (clear and on_car), (slot, cell)
        assert target[slot, cell], (slot, cell)
    assert started_on_slot > 10


@pytest.mark.slow
def test_plan_control_drives_at_the_planner_speed_with_its_angles(planner, layout):
    pose = grid_poses(planner.grid, "cpu")[::997]
    n = pose.shape[0]
    slot = torch.arange(n) % layout.num_slots
    v, delta, cost = plan_control(planner, pose, torch.zeros(n), slot)
    assert v.shape == delta.shape == cost.shape == (n,)
    assert set(v.abs().unique().tolist()) <= {0.0, COARSE.speed}
    assert torch.isin(delta, planner.prim.steer).all()
    assert (v != 0).any() and (cost[v == 0] >= 500).all()


@pytest.mark.slow
def test_a_kept_gear_is_the_cars_wherever_a_look_ahead_in_it_is_open(planner, layout):
    pose = grid_poses(planner.grid, "cpu")[::97]
    n = pose.shape[0]
    slot = torch.arange(n) % layout.num_slots
    for moving in (1.0, -1.0):
        speed = torch.full((n,), moving * COARSE.speed)
        free, _, _ = plan_control(planner, pose, speed, slot)
        kept, _, _ = plan_control(planner, pose, speed, slot, torch.ones(n, dtype=torch.bool))
        none, _, _ = plan_control(planner, pose, speed, slot, torch.zeros(n, dtype=torch.bool))
        assert torch.equal(none, free)
        other = (free * moving < 0) & (kept != 0)
        assert other.any()  # rows where the greedy choice would change gear
        # kept: the car's gear, unless every look-ahead in it is blocked (then the free one)
        assert ((kept * moving > 0) | torch.eq(kept, free)).all()
        assert (kept[other] * moving > 0).any()


@pytest.mark.slow
def test_with_a_car_margin_no_arc_taken_brings_the_grown_box_onto_a_parked_car(planner):
    # cars near the lanes' edges at 90 %: the control reads only slots, so some of its arcs
    # end with the box grown by 0.3 m on a parked car it was clear of; with the margin none do
    n = 2048
    env = ParkingEnv(n, seed=2, config=ParkingConfig(occupancy=0.9))
    env.reset()
    sim = env.state
    pose = grid_poses(planner.grid, "cpu")[torch.randperm(planner.grid.cells,
                                                          generator=torch.Generator()
                                                          .manual_seed(0))[:n]]
    margin = 0.3
    cars = (env.world, sim.present)

    def grown_touches(p):
        return touches_obstacle(fence(p, env.config.vehicle, margin), env.world, sim.present)

    def newly_near(control):
        v, delta, _ = control
        prim = planner.control  # the arc each row drives: its gear's at its angle
        taken = ((torch.sign(prim.travel) == torch.sign(v)[:, None])
                 & (prim.steer == delta[:, None])).float().argmax(-1)
        end = arcs(pose, prim.travel, prim.curvature)[torch.arange(n), taken]
        return (v != 0) & grown_touches(end) & ~grown_touches(pose)

    plain = plan_control(planner, pose, torch.zeros(n), sim.goal_slot)
    kept = planner._replace(cfg=dataclasses.replace(COARSE, car_margin=margin))
    assert newly_near(plain).sum() >= 2
    assert not newly_near(plan_control(kept, pose, torch.zeros(n), sim.goal_slot,
                                       cars=cars)).any()
    # no cars given, or no margin: the plain control
    for control in (plan_control(kept, pose, torch.zeros(n), sim.goal_slot),
                    plan_control(planner, pose, torch.zeros(n), sim.goal_slot, cars=cars)):
        assert all(torch.equal(a, b) for a, b in zip(control, plain, strict=True))


def test_gear_hold_counts_the_travel_since_the_last_change_of_gear():
    hold = GearHold(1.0, 3, "cpu")
    fresh, old = torch.tensor([True, True, True]), torch.zeros(3, dtype=torch.bool)
    assert not hold.keep(torch.zeros(3), fresh, 0.5).any()  # nothing moved yet
    # 2 m/s x 0.5 s = 1 m per step; row 1 goes 0.4 m per step, row 2 stands
    speeds = torch.tensor([2.0, 0.8, 0.0])
    assert hold.keep(speeds, old, 0.5).tolist() == [False, True, False]  # 1 m, 0.4 m: changed
    assert hold.keep(speeds, old, 0.5).tolist() == [False, True, False]  # 2 m, 0.8 m
    assert hold.keep(speeds, old, 0.5).tolist() == [False, False, False]  # 1.2 m
    assert hold.keep(-speeds, old, 0.5).tolist() == [False, True, False]  # reversed: 1 m, 0.4
    assert hold.keep(torch.zeros(3), old, 0.5).tolist() == [False, True, False]  # a stop
    assert hold.keep(-speeds, old, 0.5).tolist() == [False, True, False]  # same gear: 0.8 m
    assert not hold.keep(-speeds, torch.tensor([False, True, False]), 0.5)[1]  # a new episode


@pytest.mark.parametrize("field, value", [("cell", 0.0), ("cell", math.nan), ("headings", 4),
                                          ("headings", True), ("steers", 1),
                                          ("reverse_cost", -1.0), ("margin", math.inf),
                                          ("clearance", -0.1), ("band_cost", math.nan),
                                          ("slot_cost", 0.5), ("slot_cost", math.nan),
                                          ("reach_min", 8.0), ("speed", -2.0),
                                          ("control_step", 0.0), ("law_reach", 6.0),
                                          ("law_lateral", 0.4), ("law_heading", 4.0),
                                          ("law_heading", math.nan), ("law_reach", True),
                                          ("law_lateral", math.inf), ("gear_hold", -1.0),
                                          ("gear_hold", math.inf)])
def test_bad_planner_settings_are_refused_by_name(field, value):
    with pytest.raises((ValueError, TypeError), match=f"PlannerConfig.{field}"):
        PlannerConfig(**{field: value})


def test_the_laws_funnel_is_the_target_unless_widened():
    law = DockingConfig(gain=9.0, settle=0.05)
    target = PlannerConfig().law_funnel(law)
    assert (target.reach, target.lateral, target.heading) == (7.0, 0.5, 0.25)
    wide = PlannerConfig(law_reach=8.0, law_lateral=2.0, law_heading=1.0).law_funnel(law)
    assert (wide.reach, wide.lateral, wide.heading) == (8.0, 2.0, 1.0)
    assert (wide.gain, wide.settle) == (9.0, 0.05)  # the rest of the law is kept
    only = PlannerConfig(law_lateral=2.0).law_funnel(law)
    assert (only.reach, only.lateral, only.heading) == (7.0, 2.0, 0.25)


@pytest.mark.slow
def test_the_expert_is_evaluated_like_a_checkpoint(tmp_path, capsys):
    """PlannerExpert drives an env built with its aids (any other is refused by name), and
    the evaluator runs it on its lots; its command line refuses what does not apply."""
    from trainers.evaluate import (
        Agent,
        composition,
        evaluate_agent,
        load_expert,
        paper_lots,
    )
    from trainers.evaluate import main as evaluate_main

    config = ExpertConfig(planner=dataclasses.replace(COARSE, law_reach=8.0, law_lateral=2.0,
                                                      law_heading=1.0))
    with pytest.raises(ValueError, match="env must be built with the expert's aids"):
        PlannerExpert(ParkingEnv(2, seed=0), config)
    agent = Agent(paper_lots(config.aids()), lambda env: PlannerExpert(env, config), 300,
                  composition(config.aids(), "the planner", expert=True))
    rows = evaluate_agent(agent, episodes=4, levels=(0.0,))
    assert rows[0]["agent"] == "hand-written: approach planner + emergency brake + docking law"
    assert rows[0]["collision"] == 0.0 and 0 <= rows[0]["success"] <= 1
    with pytest.raises(ValueError, match=r"--expert must be one of \['planner', 'teacher'\]"):
        load_expert("oracle")
    for argv, message in ((["--expert", "planner"], "--expert needs --out DIR"),
                          (["x.pt", "--expert", "planner", "--out", str(tmp_path)],
                           "give a checkpoint or --expert NAME"),
                          (["--expert", "planner", "--out", str(tmp_path), "--sample", "1"],
                           "--aids and --sample apply to a checkpoint's policy")):
        with pytest.raises(SystemExit):
            evaluate_main(argv)
        assert message in capsys.readouterr().err
    assert not (tmp_path / "evaluation.md").exists()
