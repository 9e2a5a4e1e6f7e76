"""Policy features: the goal in the vehicle's frame (geometry by hand), the rays'
clearance (against a ray cast from outside the box, and the env's own collisions), the gear
and its travel (against the planner's gear hold following the same cars); the transforms'
specs and keys."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import check_env_specs

from tests.reference import _corners, _edges, _inside, _ray_hit
from torchpark import (
    ClearanceFeatures,
    GearTravelFeatures,
    GoalFrameFeatures,
    ParkingConfig,
    ParkingEnv,
    ScanMemory,
    SlotGaps,
)
from torchpark.aids.config import AidsConfig
from torchpark.experts.planner import GearHold
from torchpark.sim.vehicle import gear_travel
from torchpark.transforms.features import (
    box_edge_distance,
    goal_in_vehicle_frame,
)
from torchpark.transforms.sync_free import SyncFreeEnv


def observation(dx, dy, psi, alpha) -> torch.Tensor:
    nav = [dx, dy, math.cos(psi), math.sin(psi), 0.0, math.cos(alpha), math.sin(alpha)]
    return torch.tensor([nav + [1.0] * 16])


@pytest.mark.parametrize("dx, dy, psi, alpha, ex, ey, err", [
    (3.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0),  # goal straight ahead
    (0.0, 3.0, math.pi / 2, math.pi / 2, 3.0, 0.0, 0.0),  # facing +y, goal ahead
    (0.0, 3.0, 0.0, math.pi / 2, 0.0, 3.0, math.pi / 2),  # goal on the left, turned left
    (-2.0, 0.0, math.pi / 2, -math.pi / 2 + 0.1, 0.0, 2.0, -math.pi + 0.1),  # left, reversed
    (1.0, 1.0, -3 * math.pi / 4, math.pi, -math.sqrt(2), 0.0, -math.pi / 4),
])
def test_goal_seen_from_the_car(dx, dy, psi, alpha, ex, ey, err):
    f = goal_in_vehicle_frame(observation(dx, dy, psi, alpha), precision=0.01)[0]
    assert f[0].item() == pytest.approx(ex, abs=1e-5)
    assert f[1].item() == pytest.approx(ey, abs=1e-5)
    assert (f[2].item(), f[3].item()) == pytest.approx((math.cos(err), math.sin(err)), abs=1e-6)
    assert f[4].item() == pytest.approx(math.asinh(ex / 0.01), abs=1e-3)
    assert f[6].item() == pytest.approx(math.asinh(math.atan2(math.sin(err), math.cos(err))
                                                   / 0.01), abs=1e-3)


def test_transform_appends_features_and_keeps_the_observation():
    env = TransformedEnv(ParkingEnv(4, seed=0), GoalFrameFeatures())
    check_env_specs(env)
    td = env.reset()
    assert td["observation_policy"].shape == (4, 30)
    torch.testing.assert_close(td["observation_policy"][:, :23], td["observation"])
    torch.testing.assert_close(td["observation_policy"][:, 23:],
                               goal_in_vehicle_frame(td["observation"]))


def test_bad_arguments_are_errors():
    with pytest.raises(ValueError, match="precision must be > 0"):
        GoalFrameFeatures(precision=0.0)
    with pytest.raises(ValueError, match=">= 7 features"):
        goal_in_vehicle_frame(torch.zeros(3, 5))


@pytest.mark.parametrize("n_rays, length, width", [(16, 5.0, 2.0), (7, 4.0, 1.5), (32, 3.0, 3.0)])
def test_box_edge_distance_against_a_ray_cast_from_outside(n_rays, length, width):
    """The edge along each ray from the centre, against the reference's segment-crossing ray
    cast back from 100 m out (float64)."""
    box = _corners(0.0, 0.0, 0.0, length / 2, width / 2)
    edge = box_edge_distance(n_rays, length, width)
    for k in range(n_rays):
        d = np.array([math.cos(2 * math.pi * k / n_rays), math.sin(2 * math.pi * k / n_rays)])
        expected = 100.0 - _ray_hit(100.0 * d, -d, _edges(box))
        assert edge[k].item() == pytest.approx(expected, rel=1e-6)


def test_no_ray_sees_an_obstacle_inside_the_car_unless_it_collides():
    """Where the ego box touches nothing, every ray's first hit lies outside it: each gap is
    >= 0 (up to float32 rounding of a 20 m range). Random driving in full lots comes within
    centimetres of the cars, so a wrong edge (the box's length across it) would show."""
    base = ParkingEnv(64, seed=3, config=ParkingConfig(max_steps=200))
    base.occupancy = 0.9
    env = TransformedEnv(base, ClearanceFeatures(base.config, precision=1.0))
    td = env.rollout(60, break_when_any_done=False)
    gap = torch.sinh(td["next", "observation_policy"][..., 23:])  # precision 1 m: the gap
    clear = ~td["next", "collision"][..., 0]
    assert clear.any() and (~clear).any()
    assert gap[clear].min().item() >= -1e-4
    assert gap[clear].amin(-1).min().item() < 0.3  # it came close


def test_clearance_extends_the_goal_features_in_place():
    base = ParkingEnv(4, seed=0)
    env = TransformedEnv(base, Compose(GoalFrameFeatures(),
                                       ClearanceFeatures(base.config, "observation_policy",
                                                         "observation_policy")))
    check_env_specs(env)
    td = env.reset()
    assert td["observation_policy"].shape == (4, 46)
    torch.testing.assert_close(td["observation_policy"][:, :30],
                               torch.cat([td["observation"],
                                          goal_in_vehicle_frame(td["observation"])], -1))
    edge = box_edge_distance(16, 5.0, 2.0)
    torch.testing.assert_close(td["observation_policy"][:, 30:],
                               torch.asinh((td["observation"][:, 7:] * 20.0 - edge) / 0.1))


def test_bad_clearance_arguments_are_errors():
    with pytest.raises(ValueError, match="precision must be > 0"):
        ClearanceFeatures(ParkingConfig(), precision=float("nan"))
    with pytest.raises(ValueError, match=">= 23 features"):
        ClearanceFeatures(ParkingConfig())._apply_transform(torch.zeros(3, 20))


def test_gear_travel_restarts_on_a_change_and_keeps_the_gear_at_a_standstill():
    gear, travel = torch.zeros(1), torch.full((1,), math.inf)
    seen = []
    for speed in (2.0, 2.0, 0.0, 1.0, -1.0, -0.5, 0.0, 3.0):
        gear, travel = gear_travel(torch.tensor([speed]), gear, travel, 0.1)
        seen.append((gear.item(), round(travel.item(), 6)))
    assert seen == [(1.0, 0.2), (1.0, 0.4), (1.0, 0.4), (1.0, 0.5), (-1.0, 0.1), (-1.0, 0.15),
                    (-1.0, 0.15), (1.0, 0.3)]


@pytest.mark.parametrize("sync_free", [False, True])
def test_gear_features_count_what_the_planners_hold_counts(sync_free):
    """Random driving with episodes ending (collisions, partial resets through
    step_and_maybe_reset; torchrl's path, and the trainer's SyncFreeEnv with the reset in
    the step): after every step the features hold the gear and the travel (to the cap) that
    the teacher's gear hold, following the same cars, counts before the next action; a new
    episode starts with no gear and the full travel."""
    n, cap = 64, 2.0
    env = ParkingEnv(n, seed=3, reset_in_step=sync_free)
    env.occupancy = 0.9
    features = GearTravelFeatures(env.config.vehicle.dt, cap=cap)
    tenv = (SyncFreeEnv if sync_free else TransformedEnv)(env, features)
    hold = GearHold(1.0, n, "cpu")
    generator = torch.Generator().manual_seed(0)
    td = tenv.reset()
    assert torch.equal(td["observation_policy"][:, -2:],
                       torch.tensor([[0.0, 1.0]]).expand(n, 2))
    ends = 0
    for _ in range(60):
        hold.keep_in(env.state, env)
        expected = torch.stack([hold.gear, hold.travel.clamp(max=cap) / cap], -1)
        assert torch.allclose(td["observation_policy"][:, -2:], expected, atol=1e-6)
        assert torch.equal(td["observation_policy"][:, :-2], td["observation"])
        action = (torch.rand(n, 2, generator=generator) * 2 - 1) * torch.tensor([5.0, 0.785])
        action[:8, 0] = 0.0  # standing still keeps the gear
        td["action"] = action
        td, td = tenv.step_and_maybe_reset(td)
        ends += int(env.state.steps.eq(0).sum())
    assert ends > 0  # some rows were reset along the way


def test_gear_features_without_history_and_bad_arguments():
    obs = torch.zeros(3, 23)
    obs[:, 4] = torch.tensor([-1.5, 0.0, 2.0])
    out = GearTravelFeatures(0.1, cap=1.5)(TensorDict({"observation": obs}, [3]))
    assert torch.equal(out["observation_policy"][:, -2:],
                       torch.tensor([[-1.0, 1.0], [0.0, 1.0], [1.0, 1.0]]))
    for kwargs, name in (({"step_time": 0.0}, "step_time"), ({"step_time": 0.1, "cap": 0.0},
                                                               "cap"),
                         ({"step_time": 0.1, "cap": math.inf}, "cap"),
                         ({"step_time": True}, "step_time"), ({"step_time": "0.1"}, "step_time"),
                         ({"step_time": math.nan}, "step_time")):
        with pytest.raises(ValueError, match=name):
            GearTravelFeatures(**kwargs)
    env = TransformedEnv(ParkingEnv(2, seed=0), GearTravelFeatures(0.1))
    with pytest.raises(RuntimeError, match="reset"):
        env.transform._step(TensorDict({}, [2]), env.base_env.reset())


def scan_points(pose: np.ndarray, lidar: np.ndarray, cfg: ParkingConfig) -> np.ndarray:
    """Reference: the world (x, y) where each ray of a scan from rear-axle poses (N, 3) ends
    ((N, R) metres), float64: (N, R, 2)."""
    x, y, psi = pose.T
    cx = x + cfg.vehicle.centre_offset * np.cos(psi)
    cy = y + cfg.vehicle.centre_offset * np.sin(psi)
    angles = psi[:, None] + 2 * np.pi * np.arange(lidar.shape[1]) / lidar.shape[1]
    return np.stack([cx[:, None] + lidar * np.cos(angles),
                     cy[:, None] + lidar * np.sin(angles)], -1)


def sector_bounds(points: np.ndarray, pose: np.ndarray, cfg: ParkingConfig, slack: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Reference: the smallest gap (m) from the box at rear-axle poses (N, 3) to the world
    points (N, P, 2) in each ray's sector, float64, as (N, R) bounds for a float32 result:
    over the points within ``slack`` rad of the sector (low) and over those ``slack`` rad
    inside it (high), each clamped to the range."""
    x, y, psi = pose.T
    c, s = np.cos(psi)[:, None], np.sin(psi)[:, None]
    px = points[..., 0] - (x + cfg.vehicle.centre_offset * np.cos(psi))[:, None]
    py = points[..., 1] - (y + cfg.vehicle.centre_offset * np.sin(psi))[:, None]
    qx, qy = c * px + s * py, -s * px + c * py
    gap = np.hypot(np.maximum(np.abs(qx) - cfg.vehicle.length / 2, 0),
                   np.maximum(np.abs(qy) - cfg.vehicle.width / 2, 0))
    rays = cfg.lidar.n_rays
    width = 2 * np.pi / rays
    # each point's angle from each ray's axis, wrapped to [-pi, pi)
    off = (np.arctan2(qy, qx)[..., None] - width * np.arange(rays) + np.pi) % (2 * np.pi) - np.pi
    bounds = []
    for edge in (width / 2 + slack, width / 2 - slack):
        within = np.abs(off) <= edge
        bounds.append(np.where(within, gap[..., None], np.inf).min(1))
    return tuple(np.minimum(b, cfg.lidar.max_range) for b in bounds)


@pytest.mark.parametrize("sync_free", [False, True])
def test_scan_memory_holds_the_scans_before_seen_from_the_car_now(sync_free):
    """Random driving in dense lots with episodes ending (torchrl's step_and_maybe_reset and
    the trainer's SyncFreeEnv): after every step each feature is the smallest gap from the
    box now to where a ray of this scan or of the last three of the same episode ended, in
    that ray's sector (the env's own poses and LIDAR, a float64 reference; a point within
    1e-4 rad of a sector's edge may fall either side); a new episode fills the memory with
    its first scan."""
    n, scans = 32, 3
    env = ParkingEnv(n, seed=5, reset_in_step=sync_free)
    env.occupancy = 0.9
    cfg = env.config
    tenv = (SyncFreeEnv if sync_free else TransformedEnv)(
        env, ScanMemory(cfg, scans, "observation", "observation_policy"))
    generator = torch.Generator().manual_seed(1)
    td = tenv.reset()
    first = scan_points(env.state.pose.double().numpy(),
                        td["observation"][:, 7:].double().numpy() * cfg.lidar.max_range, cfg)
    last, trail = first, [first] * scans  # the scan now; the memory, newest first
    ends = 0
    for step in range(40):
        pose = env.state.pose.double().numpy()
        low, high = sector_bounds(np.concatenate([last, *trail], 1), pose, cfg, 1e-4)
        got = torch.sinh(td["observation_policy"][:, 23:].double()).numpy() * 0.1
        assert got.shape == (n, 16)
        assert (got >= low - 2e-4).all() and (got <= high + 2e-4).all(), f"step {step}"
        assert torch.equal(td["observation_policy"][:, :23], td["observation"])
        action = (torch.rand(n, 2, generator=generator) * 2 - 1) * torch.tensor([5.0, 0.785])
        td["action"] = action
        td, td = tenv.step_and_maybe_reset(td)
        now = scan_points(env.state.pose.double().numpy(),
                          td["observation"][:, 7:].double().numpy() * cfg.lidar.max_range, cfg)
        fresh = env.state.steps.eq(0).numpy()[:, None, None]
        ends += int(fresh.sum())
        # the next features read the scans before them: the one just left joins the memory
        trail = [np.where(fresh, now, t) for t in [last, *trail[:-1]]]
        last = now
    assert ends > 0  # some rows were reset along the way


def test_scan_memory_without_history_and_bad_arguments():
    """A batch of states outside an env remembers its own scan: each sector's gap is at most
    the clearance along its ray (whose end lies in it), and in some sectors another ray's
    end is nearer; bad arguments name themselves."""
    cfg = ParkingConfig()
    env = ParkingEnv(16, seed=2)
    env.occupancy = 0.6
    td = env.reset()
    out = ScanMemory(cfg, 2)(td.select("observation"))
    gap = torch.sinh(out["observation_policy"][:, 23:]) * 0.1
    assert gap.shape == (16, 16)
    clearance = td["observation"][:, 7:] * cfg.lidar.max_range - box_edge_distance(
        16, cfg.vehicle.length, cfg.vehicle.width)
    assert (gap <= clearance.clamp_min(0) + 1e-4).all()
    assert (gap < clearance - 0.05).any()  # a sector where another ray's end is nearer
    for scans in (0, 65, 1.5, True, "2"):
        with pytest.raises(ValueError, match="scans"):
            ScanMemory(cfg, scans)
    with pytest.raises(ValueError, match="precision"):
        ScanMemory(cfg, 1, precision=0.0)
    with pytest.raises(ValueError, match="observation"):
        ScanMemory(cfg, 1)(TensorDict({"observation": torch.zeros(2, 10)}, [2]))
    tenv = TransformedEnv(ParkingEnv(2, seed=0), ScanMemory(cfg, 1))
    with pytest.raises(RuntimeError, match="reset"):
        tenv.transform._step(TensorDict({}, [2]), tenv.base_env.reset())


@pytest.mark.slow
def test_slot_gaps_against_a_ray_cast_to_every_other_slot():
    """Random driving in an empty lot and a full one, episodes ending along the way: after
    every step each ray's feature is the gap from the car's box to the nearest slot
    rectangle but the goal's along it (< 0 where the slot reaches into the box), within
    0.1 mm of the reference's float64 ray cast from the env's own pose to each slot's
    corners; except where that cast is ill-posed (turned 1e-6 rad either way, its hit moves
    by more than 0.1 mm: a ray along a row of slots' lines), under 1 % of the rays. The
    observation passes through unchanged."""
    cfg = ParkingConfig(max_steps=30)
    edge = box_edge_distance(16, cfg.vehicle.length, cfg.vehicle.width).double().numpy()

    def cast(centre: tuple, angle: float, edges: list, inside: bool) -> float:
        """The reference's ray cast to the ``edges`` of every slot but the goal's (0 from
        inside one of them), at most the LIDAR's range."""
        hit = 0.0 if inside else _ray_hit(centre, (math.cos(angle), math.sin(angle)), edges)
        return min(hit, cfg.lidar.max_range)

    for occupancy in (0.0, 0.9):
        env = ParkingEnv(16, seed=4, config=cfg, aids=AidsConfig(observe_position=True))
        env.occupancy = occupancy
        slots = [_corners(*box) for box in env.layout.slots.double().tolist()]
        tenv = TransformedEnv(env, SlotGaps(cfg, "observation", "position",
                                            "observation_policy"))
        check_env_specs(tenv)
        generator = torch.Generator().manual_seed(2)
        td = tenv.reset()
        over = near = ill_posed = 0
        for _ in range(40):
            got = torch.sinh(td["observation_policy"][:, 23:].double()).numpy() * 0.1
            assert torch.equal(td["observation_policy"][:, :23], td["observation"])
            pose = env.state.pose.double().numpy()
            goal = env.state.goal_slot.tolist()
            for i in range(16):
                x, y, psi = pose[i]
                centre = (x + cfg.vehicle.centre_offset * math.cos(psi),
                          y + cfg.vehicle.centre_offset * math.sin(psi))
                others = [box for j, box in enumerate(slots) if j != goal[i]]
                edges = [edge for box in others for edge in _edges(box)]
                inside = any(_inside(centre, box) for box in others)
                for k in range(16):
                    angle = psi + 2 * math.pi * k / 16
                    hit = cast(centre, angle, edges, inside)
                    turned = [cast(centre, angle + t, edges, inside) for t in (-1e-6, 1e-6)]
                    if max(abs(h - hit) for h in turned) > 1e-4:
                        ill_posed += 1
                        continue
                    assert got[i, k] == pytest.approx(hit - edge[k], abs=1e-4)
                    over += hit < edge[k]
                    near += 0.0 < hit - edge[k] < 1.0
            td["action"] = (torch.rand(16, 2, generator=generator) * 2 - 1) * torch.tensor(
                [5.0, 0.785])
            td, td = tenv.step_and_maybe_reset(td)
        assert near > 0 and over > 0  # cars near a slot's line, and over one
        assert ill_posed <= 100  # of 10,240 rays (46 at 0 %, 55 at 90 %)


def test_slot_gaps_need_the_position_and_a_good_precision():
    cfg = ParkingConfig()
    with pytest.raises(ValueError, match="precision"):
        SlotGaps(cfg, precision=0.0)
    td = ParkingEnv(2, seed=0).reset()
    with pytest.raises(KeyError, match="observe_position"):
        SlotGaps(cfg)(td)
    with pytest.raises(ValueError, match=">= 7 features"):
        SlotGaps(cfg)(TensorDict({"observation": torch.zeros(2, 3),
                                  "position": torch.zeros(2, 2)}, [2]))
