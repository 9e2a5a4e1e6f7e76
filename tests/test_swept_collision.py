"""The collision test along a step's motion (``ParkingConfig.collision_substeps``) against an
independent float64 reference that samples each step's motion densely (numpy, corners and
edge normals, no code shared with torchpark's centre/half-extent SAT)."""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import numpy as np
import pytest
import torch

from torchpark import ParkingConfig, ParkingEnv
from torchpark.sim.step import move
from torchpark.sim.vehicle import bicycle_step

SAMPLES = 2001  # poses per step of dt in the reference: any point moves < 0.3 mm between two
# Metres: float32 against float64 (poses within ~1e-5 m); on the clear side also the
# reference's sampling, which can miss up to 0.3 mm of a contact.
FLOAT_BAND = 1e-4
CLEAR_BAND = 5e-4


def corners(x: np.ndarray, y: np.ndarray, heading: np.ndarray, front, rear, half_width
            ) -> np.ndarray:
    """Corners [..., 4, 2] of boxes that reach ``front`` ahead of and ``rear`` behind their
    reference point (x, y) along ``heading``, ``half_width`` to each side (all [...])."""
    c, s = np.cos(heading)[..., None], np.sin(heading)[..., None]
    front, rear, half_width = (np.asarray(t, dtype=np.float64)[..., None]
                               for t in (front, rear, half_width))
    along = np.concatenate((front, front, -rear, -rear), axis=-1)
    side = np.concatenate((-half_width, half_width, half_width, -half_width), axis=-1)
    return np.stack((x[..., None] + along * c - side * s,
                     y[..., None] + along * s + side * c), axis=-1)


def depth(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Penetration depth of convex quadrilaterals p [..., 4, 2] and q [..., 4, 2], metres [...]:
    the least distance either must move to part, over the edge normals of both (negative: they
    are apart by that much)."""
    # Corner-major copies (4, 2, ...): every operation below is elementwise over the batch.
    pc, qc = (np.ascontiguousarray(np.moveaxis(poly, (-2, -1), (0, 1))) for poly in (p, q))
    least = np.full(np.broadcast_shapes(p.shape[:-2], q.shape[:-2]), np.inf)
    for poly in (pc, qc):
        for i in range(4):
            ex, ey = poly[(i + 1) % 4, 0] - poly[i, 0], poly[(i + 1) % 4, 1] - poly[i, 1]
            norm = np.sqrt(ey * ey + ex * ex)
            ax, ay = -ey / norm, ex / norm  # the edge's unit normal
            pp = [pc[k, 0] * ax + pc[k, 1] * ay for k in range(4)]
            qq = [qc[k, 0] * ax + qc[k, 1] * ay for k in range(4)]
            overlap = np.minimum(_max4(pp) - _min4(qq), _max4(qq) - _min4(pp))
            least = np.minimum(least, overlap)
    return least


def _max4(v: list[np.ndarray]) -> np.ndarray:
    return np.maximum(np.maximum(v[0], v[1]), np.maximum(v[2], v[3]))


def _min4(v: list[np.ndarray]) -> np.ndarray:
    return np.minimum(np.minimum(v[0], v[1]), np.minimum(v[2], v[3]))


def deepest_contact(pose: np.ndarray, v: np.ndarray, delta: np.ndarray, obstacles: np.ndarray,
                    cfg: ParkingConfig) -> np.ndarray:
    """The deepest penetration, metres (B,), of the car into any obstacle (M, 5) over the
    motion of one Euler step of dt from ``pose`` (B, 3) at (v, delta) (B,), sampled at SAMPLES
    fractions s of dt: the rear axle straight along the start heading, the heading turning
    uniformly (the step's motion as torchpark.sim.vehicle.motion_poses defines it). Pairs
    apart by more than any point of the car travels in a step at s = 0, 1/2 and 1 are
    sampled there only (between those, any point moves a quarter of that)."""
    car = cfg.vehicle

    def car_corners(s: np.ndarray, rows: np.ndarray) -> np.ndarray:  # (rows, S, 4, 2)
        step = (v[rows] * car.dt)[:, None] * s[None, :]
        x = pose[rows, 0:1] + step * np.cos(pose[rows, 2:3])
        y = pose[rows, 1:2] + step * np.sin(pose[rows, 2:3])
        heading = pose[rows, 2:3] + step * np.tan(delta[rows])[:, None] / car.wheelbase
        return corners(x, y, heading, car.length - car.rear_overhang, car.rear_overhang,
                       car.width / 2)

    travel = cfg.collision_miss_depth * 2 * cfg.collision_substeps  # any point, one step
    ox, oy, oh, ol, ow = obstacles.T
    obstacle_corners = corners(ox, oy, oh, ol, ol, ow)  # (M, 4, 2)
    every = np.arange(pose.shape[0])
    coarse = car_corners(np.array([0.0, 0.5, 1.0]), every)
    dense_s = np.linspace(0.0, 1.0, SAMPLES)
    deepest = np.full(pose.shape[0], -np.inf)
    for m in range(obstacles.shape[0]):
        apart = depth(coarse, obstacle_corners[m]).max(-1)
        deepest = np.maximum(deepest, apart)
        near = np.flatnonzero(apart > -travel / 4)
        if near.size:
            found = depth(car_corners(dense_s, near), obstacle_corners[m]).max(-1)
            deepest[near] = np.maximum(deepest[near], found)
    return deepest


def fast_steps(env: ParkingEnv, count: int, rng: np.random.Generator
               ) -> tuple[np.ndarray, np.ndarray]:
    """``count`` fast steps near the parked cars of a full lot: rear-axle start poses
    (count, 3) clear of every obstacle by > 5 mm and actions (count, 2) (v, delta), float32.
    Half start anywhere within 4 m of a parked car; the other half pass a corner of the car's
    box within 0.15 m of a parked car's corner at mid-step, where a contact can begin and end
    between the two end poses."""
    car = env.config.vehicle
    obstacles = env.layout.obstacles.double().cpu().numpy()
    ox, oy, oh, ol, ow = obstacles.T
    obstacle_corners = corners(ox, oy, oh, ol, ol, ow)  # (M, 4, 2)
    front, rear, half_width = car.length - car.rear_overhang, car.rear_overhang, car.width / 2
    poses, actions = [], []
    while sum(len(p) for p in poses) < count:
        b = 4 * count
        v = rng.uniform(0.6, 1.0, b) * car.max_speed * rng.choice([-1.0, 1.0], b)
        delta = rng.uniform(-car.max_steer, car.max_steer, b)
        near = obstacles[rng.integers(len(obstacles) - 4, size=b)]  # a parked car
        anywhere = np.column_stack((near[:, 0] + rng.uniform(-4, 4, b),
                                    near[:, 1] + rng.uniform(-4, 4, b),
                                    rng.uniform(-math.pi, math.pi, b)))
        # Mid-step pose that puts one of the car's corners near one of the parked car's.
        target = corners(*near.T[:3], near[:, 3], near[:, 3], near[:, 4])[
            np.arange(b), rng.integers(4, size=b)] + rng.uniform(-0.15, 0.15, (b, 2))
        mid_heading = rng.uniform(-math.pi, math.pi, b)
        own = corners(np.zeros(b), np.zeros(b), mid_heading, front, rear, half_width)[
            np.arange(b), rng.integers(4, size=b)]  # that corner relative to the rear axle
        start_heading = mid_heading - 0.5 * v * car.dt * np.tan(delta) / car.wheelbase
        mid = target - own
        passing = np.column_stack((mid[:, 0] - 0.5 * v * car.dt * np.cos(start_heading),
                                   mid[:, 1] - 0.5 * v * car.dt * np.sin(start_heading),
                                   start_heading))
        pose = np.where(np.arange(b)[:, None] % 2 == 0, anywhere, passing).astype(np.float32)
        box = corners(*pose.astype(np.float64).T, front, rear, half_width)[:, None]
        clear = depth(box, obstacle_corners).max(-1) < -5e-3
        poses.append(pose[clear])
        actions.append(np.column_stack((v, delta)).astype(np.float32)[clear])
    return np.concatenate(poses)[:count], np.concatenate(actions)[:count]


class Cases(NamedTuple):
    """Fast steps near the parked cars of a full lot, with the reference's verdict."""

    pose: torch.Tensor  # (B, 3) float32 rear-axle start poses, clear of every obstacle
    action: torch.Tensor  # (B, 2) float32 (v, delta), within the limits
    deepest: np.ndarray  # (B,) the reference's deepest contact over the step's motion, m


@pytest.fixture(scope="module")
def cases() -> Cases:
    env = ParkingEnv(1)
    pose, action = fast_steps(env, 3000, np.random.default_rng(0))
    deepest = deepest_contact(pose.astype(np.float64), action[:, 0].astype(np.float64),
                              action[:, 1].astype(np.float64),
                              env.layout.obstacles.double().numpy(), env.config)
    return Cases(torch.from_numpy(pose), torch.from_numpy(action), deepest)


def verdict(cases: Cases, substeps: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The end poses and collision verdicts of torchpark's step (``move``) on the cases, in a
    full lot, with ``substeps`` poses tested per step."""
    env = ParkingEnv(1)
    cfg = ParkingConfig(collision_substeps=substeps)
    present = torch.ones(1, env.world.obstacles.cx.shape[0])
    return move(cases.pose, cases.action[:, 0], cases.action[:, 1], present, env.world, cfg)


@pytest.mark.slow
@pytest.mark.parametrize("substeps", [1, 4, 8])
def test_substeps_catch_every_contact_deeper_than_the_bound_and_invent_none(cases, substeps):
    cfg = ParkingConfig(collision_substeps=substeps)
    end, hit = verdict(cases, substeps)
    assert torch.equal(end, bicycle_step(cases.pose, cases.action[:, 0], cases.action[:, 1],
                                         cfg.vehicle))
    hit, deepest = hit.numpy(), cases.deepest
    # Every contact deeper than the bound is caught; no step whose whole motion is clear is
    # reported as a collision.
    assert hit[deepest > cfg.collision_miss_depth + FLOAT_BAND].all()
    assert not hit[deepest < -CLEAR_BAND].any()
    # The cases reach both sides of the test: contacts, clear steps, and (end-pose test)
    # contacts between the end poses that it misses.
    contact = deepest > FLOAT_BAND
    assert 0.05 < contact.mean() < 0.95
    if substeps == 1:
        assert (contact & ~hit).sum() >= 20


@pytest.mark.slow
def test_more_substeps_report_the_same_collisions_and_more(cases):
    """K poses per step include the end pose, and those of every divisor of K."""
    verdicts = [verdict(cases, substeps)[1] for substeps in (1, 2, 8, 64)]
    for fewer, more in itertools.pairwise(verdicts):
        assert not (fewer & ~more).any()
    assert (verdicts[-1] & ~verdicts[0]).sum() >= 20


@pytest.mark.slow
def test_a_contact_between_two_end_poses_ends_the_episode_with_substeps(cases):
    """Steps whose car touches a parked car only between its start and end poses (found by
    the reference, deeper than 64 sub-steps can miss): the paper's end-pose test lets them
    pass, 64 sub-steps report a collision that terminates the episode with the collision
    penalty."""
    _, end_hit = verdict(cases, 1)
    deep = ParkingConfig(collision_substeps=64).collision_miss_depth + FLOAT_BAND
    between = np.flatnonzero((cases.deepest > deep) & ~end_hit.numpy())[:8]
    assert len(between) == 8
    outs = {}
    for substeps in (1, 64):
        env = ParkingEnv(8, seed=0, config=ParkingConfig(occupancy=1.0,
                                                          collision_substeps=substeps))
        env.reset()
        placed = env.set_state(env.state._replace(pose=cases.pose[between],
                                                  present=torch.ones_like(env.state.present)))
        outs[substeps] = env.step(placed.set("action", cases.action[between]))["next"]
    assert not outs[1]["collision"].any() and not outs[1]["done"].any()
    assert outs[64]["collision"].all() and outs[64]["terminated"].all()
    penalty = ParkingConfig().reward.collision_penalty
    assert torch.allclose(outs[64]["reward"] - outs[1]["reward"], torch.tensor(penalty))
