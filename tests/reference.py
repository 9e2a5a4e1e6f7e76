"""An independent single-env reference of docs/spec.md, in plain Python and numpy (float64).

It shares no code with ``torchpark`` beyond reading the lot it is given: collision is a SAT on
projected corners (not the centre/half-extent form), LIDAR intersects each ray with each box
edge as a segment (not the slab test), and every loop is a Python loop over Python floats
(numpy only holds what it is given and returns). It is fed the lot of one
env of a batched ``ParkingEnv`` and stepped with the same actions in the lockstep test; the
throughput benchmark uses it as the per-env baseline, the way the paper's Gymnasium env steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def _wrap(angle: float) -> float:
    wrapped = math.remainder(angle, 2.0 * math.pi)  # [-pi, pi]
    return math.pi if wrapped <= -math.pi else wrapped


Point = tuple[float, float]
Polygon = tuple[Point, Point, Point, Point]


def _corners(cx: float, cy: float, heading: float, half_length: float, half_width: float
             ) -> Polygon:
    c, s = math.cos(heading), math.sin(heading)
    return tuple((cx + a * half_length * c - b * half_width * s,
                  cy + a * half_length * s + b * half_width * c)
                 for a, b in ((1, -1), (1, 1), (-1, 1), (-1, -1)))


def _edges(poly: Polygon) -> list[tuple[Point, Point]]:
    """The four edges (start, end), counter-clockwise."""
    return [(poly[i], poly[(i + 1) % 4]) for i in range(4)]


def _projections(poly: Polygon, ax: float, ay: float) -> list[float]:
    return [x * ax + y * ay for x, y in poly]


def _polygons_touch(p: Polygon, q: Polygon) -> bool:
    """SAT on two convex quadrilaterals given by corners; touching counts."""
    for poly in (p, q):
        for (x0, y0), (x1, y1) in _edges(poly):
            ax, ay = -(y1 - y0), x1 - x0
            pp, qq = _projections(p, ax, ay), _projections(q, ax, ay)
            if max(pp) < min(qq) or max(qq) < min(pp):
                return False
    return True


def _inside(point: Point, poly: Polygon) -> bool:
    """Point in a counter-clockwise convex quadrilateral, boundary included."""
    px, py = point
    for (ax, ay), (bx, by) in _edges(poly):
        if (bx - ax) * (py - ay) - (by - ay) * (px - ax) < 0:
            return False
    return True


def _ray_hit(origin: Point, direction: Point, edges: list[tuple[Point, Point]]) -> float:
    """Distance along the ray to its first crossing of the edges (inf if none); the origin
    lies outside every polygon the edges bound."""
    (ox, oy), (dx, dy) = origin, direction
    best = math.inf
    for (ax, ay), (bx, by) in edges:
        ex, ey = bx - ax, by - ay
        denom = dx * ey - dy * ex
        if denom == 0.0:
            continue  # parallel: the adjacent edges give the hit, if any
        wx, wy = ax - ox, ay - oy
        t = (wx * ey - wy * ex) / denom
        u = (wx * dy - wy * dx) / denom
        if t >= 0.0 and 0.0 <= u <= 1.0:
            best = min(best, t)
    return best


@dataclass
class ReferenceConfig:
    wheelbase: float = 4.0
    width: float = 2.0
    length: float = 5.0
    rear_overhang: float = 0.5
    dt: float = 0.1
    max_speed: float = 5.0
    max_steer: float = 0.785
    n_rays: int = 16
    max_range: float = 20.0
    weights: tuple[float, float, float, float] = (0.35, 0.35, 0.20, 0.10)
    collision_penalty: float = -200.0
    success_bonus: float = 1000.0
    success_threshold: float = 4e-4
    max_steps: int = 1000


class ReferenceParkingEnv:
    """One parking lot: obstacles (K, 5) boxes, a goal pose and a start pose, stepped in Python."""

    def __init__(self, obstacles: np.ndarray, goal: np.ndarray, pose: np.ndarray,
                 cfg: ReferenceConfig, speed: float = 0.0, steps: int = 0) -> None:
        self.cfg = cfg
        self.obstacles = [_corners(*map(float, box)) for box in np.asarray(obstacles)]
        self.edges = [edge for poly in self.obstacles for edge in _edges(poly)]
        self.goal = [float(v) for v in goal]
        self.x, self.y, self.psi = (float(v) for v in pose)
        self.v = float(speed)
        self.steps = int(steps)

    @classmethod
    def from_batched(cls, env, index: int) -> ReferenceParkingEnv:
        """The lot and state of env ``index`` of a ``torchpark.ParkingEnv``."""
        c = env.config
        cfg = ReferenceConfig(
            wheelbase=c.vehicle.wheelbase, width=c.vehicle.width, length=c.vehicle.length,
            rear_overhang=c.vehicle.rear_overhang, dt=c.vehicle.dt,
            max_speed=c.vehicle.max_speed, max_steer=c.vehicle.max_steer,
            n_rays=c.lidar.n_rays, max_range=c.lidar.max_range,
            weights=(c.reward.w_x, c.reward.w_y, c.reward.w_alpha, c.reward.w_v),
            collision_penalty=c.reward.collision_penalty, success_bonus=c.reward.success_bonus,
            success_threshold=c.reward.success_threshold, max_steps=c.max_steps,
        )
        state = env.state
        boxes = env.layout.obstacles.double().cpu().numpy()
        present = state.present[index].cpu().numpy() > 0
        return cls(boxes[present], state.goal[index].double().cpu().numpy(),
                   state.pose[index].double().cpu().numpy(), cfg,
                   speed=float(state.speed[index]), steps=int(state.steps[index]))

    def _ego(self) -> Polygon:
        cfg = self.cfg
        offset = cfg.length / 2.0 - cfg.rear_overhang
        cx = self.x + offset * math.cos(self.psi)
        cy = self.y + offset * math.sin(self.psi)
        return _corners(cx, cy, self.psi, cfg.length / 2.0, cfg.width / 2.0)

    def _centre(self) -> Point:
        """The LIDAR's origin: the mean of the car's corners."""
        ego = self._ego()
        return sum(x for x, _ in ego) / 4.0, sum(y for _, y in ego) / 4.0

    def observation(self) -> np.ndarray:
        cfg = self.cfg
        centre = self._centre()
        inside = any(_inside(centre, poly) for poly in self.obstacles)  # every ray reads 0
        lidar = []
        for k in range(cfg.n_rays):
            angle = self.psi + 2.0 * math.pi * k / cfg.n_rays
            direction = (math.cos(angle), math.sin(angle))
            nearest = 0.0 if inside else _ray_hit(centre, direction, self.edges)
            lidar.append(min(nearest, cfg.max_range) / cfg.max_range)
        gx, gy, alpha = self.goal
        nav = [gx - self.x, gy - self.y, math.cos(self.psi), math.sin(self.psi), self.v,
               math.cos(alpha), math.sin(alpha)]
        return np.array(nav + lidar)

    def collision(self) -> bool:
        ego = self._ego()
        return any(_polygons_touch(ego, poly) for poly in self.obstacles)

    # Where a float32 result may differ from this float64 one by more than rounding: the
    # decision flips on a sliver of the input. Each margin is 0 at the flip and grows with the
    # distance from it, in metres.
    def ray_margins(self) -> np.ndarray:
        """(n_rays,) per ray, the distance from the ray (origin to max_range) to the nearest
        obstacle corner it passes: a ray that grazes a corner hits or misses by a hair, and its
        reading jumps between the corner's distance and whatever lies behind."""
        cfg = self.cfg
        ox, oy = self._centre()
        corners = [(x - ox, y - oy) for poly in self.obstacles for x, y in poly]
        margins = []
        for k in range(cfg.n_rays):
            angle = self.psi + 2.0 * math.pi * k / cfg.n_rays
            c, s = math.cos(angle), math.sin(angle)
            margins.append(min((abs(-x * s + y * c) for x, y in corners
                                if 0.0 <= x * c + y * s <= cfg.max_range), default=math.inf))
        return np.array(margins)

    def contact_margin(self) -> float:
        """|SAT gap| to the nearest obstacle, metres: the largest separation (or the smallest
        penetration) along the boxes' edge normals; touching flips at 0."""
        ego = self._ego()
        best = math.inf
        for poly in self.obstacles:
            gap = -math.inf
            for box in (ego, poly):
                for (x0, y0), (x1, y1) in _edges(box):
                    norm = math.hypot(x1 - x0, y1 - y0)
                    ax, ay = -(y1 - y0) / norm, (x1 - x0) / norm
                    pp, qq = _projections(ego, ax, ay), _projections(poly, ax, ay)
                    gap = max(gap, min(qq) - max(pp), min(pp) - max(qq))
            best = min(best, abs(gap))
        return best

    def cost(self) -> float:
        wx, wy, wa, wv = self.cfg.weights
        gx, gy, alpha = self.goal
        return (wx * abs(gx - self.x) + wy * abs(gy - self.y)
                + wa * abs(_wrap(alpha - self.psi)) + wv * abs(self.v))

    def step(self, action) -> dict:
        cfg = self.cfg
        v = min(max(float(action[0]), -cfg.max_speed), cfg.max_speed)
        delta = min(max(float(action[1]), -cfg.max_steer), cfg.max_steer)
        self.x += v * math.cos(self.psi) * cfg.dt
        self.y += v * math.sin(self.psi) * cfg.dt
        self.psi = _wrap(self.psi + v / cfg.wheelbase * math.tan(delta) * cfg.dt)
        self.v = v
        self.steps += 1
        cost = self.cost()
        collision = self.collision()
        success = cost < cfg.success_threshold
        reward = 1.0 - math.cbrt(cost)
        reward += cfg.collision_penalty if collision else 0.0
        reward += cfg.success_bonus if success else 0.0
        terminated = collision or success
        truncated = self.steps >= cfg.max_steps and not terminated
        return {"observation": self.observation(), "reward": reward, "terminated": terminated,
                "truncated": truncated, "success": success, "collision": collision}
