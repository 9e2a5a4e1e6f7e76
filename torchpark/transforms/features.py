"""Policy features computed from the paper's observation: the goal in the vehicle's frame,
the clearance left along each LIDAR ray, the gear the car moves in with its travel in it
(from the observed speed over the episode), a memory of the last scans, and the slots' lines
as rays would see them (from the observation, the car's position and the lot's map).

The paper's observation gives the goal offset in the world frame; a policy then has to learn a
rotation by the heading before it can steer. These features hand it the rotated offset, and a
log-like scale (``asinh(x / precision)``) that stays informative down to the millimetres the
success test asks for, where a world-frame offset normalised by metres is flat.

The LIDAR reads from the box centre, divided by its 20 m range: a car 10 cm off the ego's side
and one touching it differ by 0.005 of a ray's range, a few hundredths of a normalised input.
The clearance features subtract the ego box's own extent along each ray and put the gap left
on the same log-like scale, where 5 cm and 50 cm are a unit apart.
"""

from __future__ import annotations

import math
from typing import Protocol, runtime_checkable

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform

from torchpark.config import ParkingConfig, is_number, require
from torchpark.sim.geometry import OrientedBoxes, oriented_boxes
from torchpark.sim.layout import build_layout
from torchpark.sim.lidar import lidar_scan, line_rotation, ray_angles
from torchpark.sim.observation import NAV_DIM, SPEED
from torchpark.sim.vehicle import gear_travel


@runtime_checkable
class EpisodeFeature(Protocol):
    """A feature that reads the episode so far (a state per env): a recurrent policy's
    state, which an agent acting outside the env (``TrainedAgent.predict``) hands back and
    takes again, one (B, ``state_width``) float tensor per feature."""

    state_width: int

    def episode_state(self, source: Tensor) -> Tensor:
        """(B, state_width): the state the next observation's features read, after a
        reset (or a :meth:`resume` and a reset) wrote the features of ``source`` (B, D)."""
        ...

    def resume(self, source: Tensor, state: Tensor, going_on: Tensor) -> None:
        """Sets the state before ``source`` (B, D) is observed: the rows ``going_on`` (B,)
        bool go on from ``state`` (B, state_width), the others start an episode. A reset
        with ``"_reset"`` = ~going_on then writes every row's features."""
        ...


GOAL_FEATURES = 7  # ex, ey, cos and sin of the heading error, three asinh scales


def goal_in_vehicle_frame(observation: Tensor, precision: float = 0.01) -> Tensor:
    """[..., NAV_DIM + n_rays] observation -> [..., GOAL_FEATURES] float features of the goal
    seen from the car.

    Features: (ex, ey) goal minus rear axle in the vehicle frame (m, x forward, y left);
    cos, sin of the heading error wrap(alpha - psi); asinh(ex / precision),
    asinh(ey / precision), asinh(heading error / precision) with ``precision`` in m (and rad).
    """
    if observation.shape[-1] < NAV_DIM:
        raise ValueError(f"observation must have >= {NAV_DIM} features, got shape "
                         f"{tuple(observation.shape)}")
    dx, dy, cos_psi, sin_psi, _, cos_alpha, sin_alpha = observation[..., :NAV_DIM].unbind(-1)
    ex = cos_psi * dx + sin_psi * dy
    ey = cos_psi * dy - sin_psi * dx
    cos_err = cos_alpha * cos_psi + sin_alpha * sin_psi
    sin_err = sin_alpha * cos_psi - cos_alpha * sin_psi
    err = torch.atan2(sin_err, cos_err)
    scale = 1.0 / precision
    return torch.stack([ex, ey, cos_err, sin_err, torch.asinh(ex * scale),
                        torch.asinh(ey * scale), torch.asinh(err * scale)], dim=-1)


def appended_spec(observation_spec: Composite, in_key: str, out_key: str, width: int
                  ) -> Composite:
    """``observation_spec`` with ``out_key``: ``in_key``'s spec ``width`` features wider."""
    source = observation_spec[in_key]
    shape = (*source.shape[:-1], source.shape[-1] + width)
    observation_spec[out_key] = Unbounded(shape=shape, dtype=source.dtype, device=source.device)
    return observation_spec


class GoalFrameFeatures(Transform):
    """Writes ``out_key`` = cat(observation, :func:`goal_in_vehicle_frame`) and keeps
    ``in_key`` (the paper's 23-dim observation) as it is.

    Args:
        in_key: the paper's observation key.
        out_key: where the [..., obs_dim + GOAL_FEATURES] policy input goes.
        precision: the length (m) and angle (rad) below which the asinh features turn linear.
    """

    def __init__(self, in_key: str = "observation", out_key: str = "observation_policy",
                 precision: float = 0.01) -> None:
        if not precision > 0:
            raise ValueError(f"precision must be > 0 (m), got {precision!r}")
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.precision = precision

    def _apply_transform(self, observation: Tensor) -> Tensor:
        features = goal_in_vehicle_frame(observation, self.precision)
        return torch.cat([observation, features], dim=-1)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
               ) -> TensorDictBase:
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        return appended_spec(observation_spec, self.in_keys[0], self.out_keys[0], GOAL_FEATURES)


def box_edge_distance(n_rays: int, length: float, width: float) -> Tensor:
    """(n_rays,) float32 distance (m) from the centre of a ``length`` x ``width`` box to its
    edge along each LIDAR ray (angles 2 pi k / n_rays from the box's long axis)."""
    angles = ray_angles(n_rays)
    along = (length / 2.0) / torch.cos(angles).abs().clamp_min(1e-12)
    across = (width / 2.0) / torch.sin(angles).abs().clamp_min(1e-12)
    return torch.minimum(along, across).to(torch.float32)


def ray_clearance(lidar: Tensor, edge: Tensor, max_range: float, precision: float = 0.1
                  ) -> Tensor:
    """[..., n_rays] LIDAR readings (distance / ``max_range``, in [0, 1]) and the (n_rays,)
    :func:`box_edge_distance` of the ego box -> [..., n_rays] ``asinh(gap / precision)``, the
    gap (m) the ray leaves between the ego box's edge and the first obstacle it meets
    (<= 0: touching; ``max_range`` - edge where nothing is in range)."""
    return torch.asinh((lidar * max_range - edge) / precision)


class ClearanceFeatures(Transform):
    """Writes ``out_key`` = cat(``in_key``, :func:`ray_clearance`), the LIDAR read from
    ``in_key``'s columns NAV_DIM .. NAV_DIM + n_rays (the paper's observation, or the policy
    input that starts with it, e.g. :class:`GoalFrameFeatures`' output).

    Args:
        config: the env's config (its vehicle's box, its LIDAR's rays and range).
        in_key: the paper's observation, or a policy input that starts with it.
        out_key: where the [..., in_dim + n_rays] policy input goes (may be ``in_key``).
        precision: the gap (m) below which the asinh turns linear.
    """

    def __init__(self, config: ParkingConfig, in_key: str = "observation",
                 out_key: str = "observation_policy", precision: float = 0.1) -> None:
        if not precision > 0:
            raise ValueError(f"precision must be > 0 (m), got {precision!r}")
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.n_rays = config.lidar.n_rays
        self.max_range = config.lidar.max_range
        self.precision = precision
        self.register_buffer("edge", box_edge_distance(self.n_rays, config.vehicle.length,
                                                       config.vehicle.width))

    def _apply_transform(self, observation: Tensor) -> Tensor:
        if observation.shape[-1] < NAV_DIM + self.n_rays:
            raise ValueError(f"{self.in_keys[0]} must have >= {NAV_DIM + self.n_rays} "
                             f"features, got shape {tuple(observation.shape)}")
        lidar = observation[..., NAV_DIM:NAV_DIM + self.n_rays]
        clearance = ray_clearance(lidar, self.edge.to(lidar.device), self.max_range,
                                  self.precision)
        return torch.cat([observation, clearance], dim=-1)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
               ) -> TensorDictBase:
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        return appended_spec(observation_spec, self.in_keys[0], self.out_keys[0], self.n_rays)


GEAR_FEATURES = 2  # the gear, the travel in it (a share of the cap)


class GearTravelFeatures(Transform):
    """Writes ``out_key`` = cat(``in_key``, gear, min(travel, cap) / cap): the gear the car
    last moved in and how far it has moved in it since it changed (:func:`gear_travel`),
    counted from the speed the observations report (column ``SPEED`` of the paper's
    observation, which ``in_key`` starts with). A new episode starts with no gear and a travel of
    ``cap``.

    The planner's gear hold keeps a new gear until the car has moved ``gear_hold`` m in it:
    a teacher with a hold labels the same observation with either gear, depending on how far
    the car came. With these features the student sees what the teacher's label depends on.

    Stateful per env (gear and travel, (N,)): ``_reset`` starts the rows it resets (all,
    or those of the ``"_reset"`` mask), each step adds the step's motion. Called on a batch
    of states outside an env (``transform(td)``), it has no history: each row's gear is its
    speed's sign and its travel ``cap``. An :class:`EpisodeFeature`: its state (B, 2) is
    the gear and the travel, m.

    Args:
        step_time: the time one action drives, s (the env's dt times its action repeat).
        in_key: the policy input that starts with the paper's observation.
        out_key: where the [..., in_dim + GEAR_FEATURES] policy input goes.
        cap: the travel (m) beyond which the feature no longer grows.
    """

    def __init__(self, step_time: float, in_key: str = "observation",
                 out_key: str = "observation_policy", cap: float = 2.0) -> None:
        for name, value in (("step_time", step_time), ("cap", cap)):
            require(is_number(value) and math.isfinite(value) and value > 0, name,
                    "a finite number > 0 (s for step_time, m for cap)", value)
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.step_time = step_time
        self.cap = cap
        self.gear: Tensor | None = None
        self.travel: Tensor | None = None
        self.state_width = GEAR_FEATURES

    def episode_state(self, source: Tensor) -> Tensor:
        """(B, 2): the gear and its travel, m, that the next observation's step adds to."""
        if self.gear is None or self.travel is None:
            raise RuntimeError("GearTravelFeatures: state before reset (reset the env first)")
        return torch.stack((self.gear, self.travel), -1)

    def resume(self, source: Tensor, state: Tensor, going_on: Tensor) -> None:
        """The gear and travel (B, 2) of ``state`` moved on by the speed of ``source``
        (B, D) where ``going_on`` (B,) bool, a start elsewhere."""
        self.gear, self.travel = gear_travel(source[..., SPEED], state[..., 0], state[..., 1],
                                             self.step_time)
        self.start_rows(~going_on)

    def _features(self, source: Tensor, gear: Tensor, travel: Tensor) -> Tensor:
        features = torch.stack([gear, travel.clamp(max=self.cap) / self.cap], dim=-1)
        return torch.cat([source, features.to(source.dtype)], dim=-1)

    def _write(self, tensordict: TensorDictBase, gear: Tensor, travel: Tensor
               ) -> TensorDictBase:
        source = tensordict.get(self.in_keys[0])
        tensordict.set(self.out_keys[0], self._features(source, gear, travel))
        return tensordict

    def _apply_transform(self, source: Tensor) -> Tensor:
        """Without history (a batch of states): the speed's sign and the full travel."""
        speed = source[..., SPEED]
        return self._features(source, torch.sign(speed), torch.full_like(speed, self.cap))

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
               ) -> TensorDictBase:
        speed = tensordict_reset.get(self.in_keys[0])[..., SPEED]
        fresh = torch.ones_like(speed, dtype=torch.bool)
        if self.gear is not None and self.gear.shape == speed.shape and tensordict is not None \
                and "_reset" in tensordict.keys():
            fresh = tensordict.get("_reset").reshape(speed.shape).to(speed.device)
        else:
            self.gear, self.travel = torch.zeros_like(speed), torch.zeros_like(speed)
        self.start_rows(fresh)
        assert self.gear is not None and self.travel is not None  # start_rows set both
        return self._write(tensordict_reset, self.gear, self.travel)

    def start_rows(self, rows: Tensor) -> None:
        """The rows ``rows`` (N,) bool start an episode: no gear, a travel of ``cap``."""
        if self.gear is None or self.travel is None:
            raise RuntimeError("GearTravelFeatures: start_rows before reset (reset the env first)")
        self.gear = torch.where(rows, 0.0, self.gear)
        self.travel = torch.where(rows, self.cap, self.travel)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
              ) -> TensorDictBase:
        if self.gear is None or self.travel is None:
            raise RuntimeError("GearTravelFeatures: step before reset (reset the env first)")
        speed = next_tensordict.get(self.in_keys[0])[..., SPEED]
        self.gear, self.travel = gear_travel(speed, self.gear, self.travel, self.step_time)
        return self._write(next_tensordict, self.gear, self.travel)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        return appended_spec(observation_spec, self.in_keys[0], self.out_keys[0], GEAR_FEATURES)


def ray_end_gaps(scans: Tensor, now: Tensor, ray_cos: Tensor, ray_sin: Tensor,
                 length: float, width: float) -> tuple[Tensor, Tensor]:
    """The gap from the car's box now to where each ray of some LIDAR scans ended, and the
    bearing it lies at.

    scans: [..., K, 4 + R] scans, each the box centre (x, y) in a frame fixed for the episode
    (m), the heading's cos and sin, and the R ray lengths (m); now: [..., 4] the box centre
    and heading now; ray_cos, ray_sin: (R,) the rays' angles from the heading; ``length`` x
    ``width``: the box (m). Returns (gap, bearing), each [..., K, R]: the distance (m) from
    each ray's end to the box now (0 inside it), and its angle from the heading now
    (atan2, rad).
    """
    cx, cy, c, s = (scans[..., k:k + 1] for k in range(4))  # [..., K, 1]
    reach = scans[..., 4:]  # [..., K, R]
    px = cx + reach * (c * ray_cos - s * ray_sin) - now[..., None, None, 0]
    py = cy + reach * (s * ray_cos + c * ray_sin) - now[..., None, None, 1]
    nc, ns = now[..., None, None, 2], now[..., None, None, 3]
    qx, qy = nc * px + ns * py, nc * py - ns * px
    gap = torch.hypot((qx.abs() - length / 2.0).clamp_min(0.0),
                      (qy.abs() - width / 2.0).clamp_min(0.0))
    return gap, torch.atan2(qy, qx)


def sector_gaps(gap: Tensor, bearing: Tensor, n_rays: int) -> Tensor:
    """[..., P] gaps (m) at bearings (rad) -> [..., n_rays] the smallest gap in each ray's
    sector (the bearings nearer to ray k's angle 2 pi k / n_rays than to any other ray's;
    inf where none lies)."""
    sector = torch.round(bearing * (n_rays / (2.0 * math.pi))).long().remainder(n_rays)
    rays = torch.arange(n_rays, device=gap.device)
    inside = sector[..., None] == rays  # [..., P, n_rays]
    return torch.where(inside, gap[..., None], math.inf).amin(-2)


class ScanMemory(Transform):
    """Writes ``out_key`` = cat(``in_key``, per ray of the car now, ``asinh(gap /
    precision)`` of the smallest gap from its box to where a ray of this scan or of the last
    ``scans`` scans ended in that ray's sector): a LIDAR as dense as the scans together.
    The 16 rays leave 22.5 degrees between them, where a parked car's corner a metre off can
    hide; as the car moves and turns, the scans before sample other angles. Pooled per
    sector, the memory hands the policy the obstacles, not the car's own recent motion
    (which a student imitating a teacher would copy). Computed from the paper's observation
    (``in_key`` starts with it) alone: the box centre's motion from the goal offset (dx, dy,
    the goal fixed in an episode) and the heading.

    Stateful per env (the last ``scans`` scans, newest first, (N, scans, 4 + n_rays)):
    ``_reset`` starts the rows it resets (all, or those of the ``"_reset"`` mask) with the
    first scan in every place; each step's features read the scans before it, then push its
    own. Called on a batch of states outside an env (``transform(td)``), it has no history:
    each row's scans are its own. An :class:`EpisodeFeature`: its state is the scans the next
    observation's features read, flattened (B, scans * (4 + n_rays)).

    Args:
        config: the env's config (its vehicle's box, its LIDAR's rays and range).
        scans: how many past scans to remember.
        in_key: the policy input that starts with the paper's observation.
        out_key: where the [..., in_dim + n_rays] input goes.
        precision: the gap (m) below which the asinh turns linear.
    """

    def __init__(self, config: ParkingConfig, scans: int, in_key: str = "observation",
                 out_key: str = "observation_policy", precision: float = 0.1) -> None:
        require(isinstance(scans, int) and not isinstance(scans, bool) and 1 <= scans <= 64,
                "scans", "an int in [1, 64]", scans)
        if not precision > 0:
            raise ValueError(f"precision must be > 0 (m), got {precision!r}")
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.scans = scans
        self.n_rays = config.lidar.n_rays
        self.max_range = config.lidar.max_range
        self.length, self.width = config.vehicle.length, config.vehicle.width
        self.offset = config.vehicle.centre_offset
        self.precision = precision
        angles = ray_angles(self.n_rays)
        self.register_buffer("ray_cos", torch.cos(angles).to(torch.float32))
        self.register_buffer("ray_sin", torch.sin(angles).to(torch.float32))
        self.history: Tensor | None = None
        self.state_width = scans * (4 + self.n_rays)

    def episode_state(self, source: Tensor) -> Tensor:
        """(B, scans * (4 + n_rays)): the scan of ``source`` (B, D) and the ones before it,
        newest first, flattened: what the next observation's features read."""
        if self.history is None:
            raise RuntimeError("ScanMemory: state before reset (reset the env first)")
        now = self.scan(source)[..., None, :]
        return torch.cat((now, self.history[..., :-1, :]), -2).flatten(-2)

    def resume(self, source: Tensor, state: Tensor, going_on: Tensor) -> None:
        """The remembered scans of ``state`` (B, scans * (4 + n_rays)); the rows not
        ``going_on`` (B,) bool are refilled by the reset that follows."""
        self.history = state.reshape(*state.shape[:-1], self.scans, 4 + self.n_rays)

    def scan(self, source: Tensor) -> Tensor:
        """[..., D] input starting with the paper's observation -> [..., 4 + n_rays]: the
        box centre from the goal (m), the heading's cos and sin, the rays' lengths (m)."""
        if source.shape[-1] < NAV_DIM + self.n_rays:
            raise ValueError(f"{self.in_keys[0]} must have >= {NAV_DIM + self.n_rays} "
                             f"features, got shape {tuple(source.shape)}")
        dx, dy, c, s = source[..., :4].unbind(-1)
        centre = torch.stack([self.offset * c - dx, self.offset * s - dy, c, s], -1)
        lidar = source[..., NAV_DIM:NAV_DIM + self.n_rays] * self.max_range
        return torch.cat([centre, lidar], -1)

    def _features(self, source: Tensor, now: Tensor, history: Tensor) -> Tensor:
        scans = torch.cat([now[..., None, :], history], dim=-2)
        gap, bearing = ray_end_gaps(scans, now[..., :4], self.ray_cos.to(source.device),
                                    self.ray_sin.to(source.device), self.length, self.width)
        pooled = sector_gaps(gap.flatten(-2), bearing.flatten(-2), self.n_rays)
        # a sector no ray end lies in (none, or only beyond the range) reads the range
        pooled = torch.asinh(pooled.clamp(max=self.max_range) / self.precision)
        return torch.cat([source, pooled.to(source.dtype)], dim=-1)

    def _repeated(self, now: Tensor) -> Tensor:
        return now[..., None, :].expand(*now.shape[:-1], self.scans, now.shape[-1])

    def _apply_transform(self, source: Tensor) -> Tensor:
        """Without history (a batch of states): every remembered scan is the row's own."""
        now = self.scan(source)
        return self._features(source, now, self._repeated(now))

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
               ) -> TensorDictBase:
        source = tensordict_reset.get(self.in_keys[0])
        now = self.scan(source)
        fresh = torch.ones(now.shape[:-1], dtype=torch.bool, device=now.device)
        if self.history is not None and self.history.shape[:-2] == now.shape[:-1] \
                and tensordict is not None and "_reset" in tensordict.keys():
            fresh = tensordict.get("_reset").reshape(fresh.shape).to(now.device)
        else:
            self.history = self._repeated(now).clone()
        self.history = torch.where(fresh[..., None, None], self._repeated(now), self.history)
        tensordict_reset.set(self.out_keys[0], self._features(source, now, self.history))
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
              ) -> TensorDictBase:
        if self.history is None:
            raise RuntimeError("ScanMemory: step before reset (reset the env first)")
        source = next_tensordict.get(self.in_keys[0])
        now = self.scan(source)
        next_tensordict.set(self.out_keys[0], self._features(source, now, self.history))
        self.history = torch.cat([now[..., None, :], self.history[..., :-1, :]], dim=-2)
        return next_tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        return appended_spec(observation_spec, self.in_keys[0], self.out_keys[0], self.n_rays)


def slot_gaps(observation: Tensor, position: Tensor, slots: OrientedBoxes, goals: Tensor,
              rotation: Tensor, edge: Tensor, offset: float, max_range: float,
              precision: float = 0.1) -> Tensor:
    """The gap along each LIDAR ray from the car's box to the nearest slot but the goal's, as
    if the slots' lines were walls.

    observation: [N, D] starting with the paper's observation (dx, dy, cos psi, sin psi: the
    goal from the rear axle, m, and the heading); position: [N, 2] the rear axle in the lot,
    m; slots: the lot's slot rectangles (S,); goals: (S, 2) each slot's goal position (its
    rear axle, m), which picks the goal's slot (the nearest to position + (dx, dy));
    rotation: :func:`~torchpark.sim.lidar.line_rotation` of the rays; edge: (R,)
    :func:`box_edge_distance` of the car's box; offset: the box centre ahead of the rear
    axle, m. Returns [N, R] ``asinh(gap / precision)``, the gap in m (< 0: the slot reaches
    into the car's box along the ray; ``max_range`` - edge where none is in range).
    """
    dx, dy, c, s = observation[:, :4].unbind(-1)
    goal = position + torch.stack((dx, dy), -1)
    goal_slot = torch.cdist(goal, goals).argmin(-1)
    present = 1.0 - torch.nn.functional.one_hot(goal_slot, goals.shape[0]).to(c.dtype)
    x, y = position[:, 0] + offset * c, position[:, 1] + offset * s
    reach = lidar_scan(x, y, c, s, rotation, slots, present, edge.shape[0], max_range)
    return torch.asinh((reach - edge) / precision)


class SlotGaps(Transform):
    """Writes ``out_key`` = cat(``in_key``, :func:`slot_gaps`): per LIDAR ray, the gap from
    the car's box to the nearest slot but the goal's. The LIDAR sees parked cars, not the
    slots' lines: in an empty lot a slot is open ground. A teacher that keeps off every slot
    but its goal's (the planner's ``slot_cost``) steers by where they are; these features let
    a student see them. Computed from the observation (``in_key``, which starts with the
    paper's), the rear axle's position in the lot (``position_key``, the env's with
    ``AidsConfig.observe_position``) and the lot's map, which is
    the same for every env.

    Args:
        config: the env's config (its lot, its vehicle's box, its LIDAR's rays and range).
        in_key: the policy input that starts with the paper's observation.
        position_key: the rear axle's (x, y) in the lot, m.
        out_key: where the [..., in_dim + n_rays] input goes (may be ``in_key``).
        precision: the gap (m) below which the asinh turns linear.
    """

    def __init__(self, config: ParkingConfig, in_key: str = "observation",
                 position_key: str = "position", out_key: str = "observation_policy",
                 precision: float = 0.1) -> None:
        require(is_number(precision) and math.isfinite(precision) and precision > 0,
                "precision", "a finite number > 0 (m)", precision)
        super().__init__(in_keys=[in_key, position_key], out_keys=[out_key])
        self.n_rays = config.lidar.n_rays
        self.max_range = config.lidar.max_range
        self.offset = config.vehicle.centre_offset
        self.precision = precision
        layout = build_layout(config.lot, config.vehicle)
        slots = oriented_boxes(layout.slots)
        for name, value in zip(OrientedBoxes._fields, slots, strict=True):
            self.register_buffer(f"slot_{name}", value.contiguous())
        self.register_buffer("goals", layout.goal_poses[:, :2].contiguous())
        self.register_buffer("rotation", line_rotation(self.n_rays))
        self.register_buffer("edge", box_edge_distance(self.n_rays, config.vehicle.length,
                                                       config.vehicle.width))

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        source = next_tensordict.get(self.in_keys[0])
        if source.shape[-1] < NAV_DIM:
            raise ValueError(f"{self.in_keys[0]} must have >= {NAV_DIM} features, got shape "
                             f"{tuple(source.shape)}")
        position = next_tensordict.get(self.in_keys[1], None)
        if position is None:
            raise KeyError(f"SlotGaps reads the car's position from {self.in_keys[1]!r}: "
                           "make the env with AidsConfig(observe_position=True)")
        slots = OrientedBoxes(*(getattr(self, f"slot_{name}") for name in OrientedBoxes._fields))
        flat = source.reshape(-1, source.shape[-1])
        gaps = slot_gaps(flat, position.reshape(-1, 2).to(source.dtype), slots, self.goals,
                         self.rotation, self.edge, self.offset, self.max_range, self.precision)
        next_tensordict.set(self.out_keys[0], torch.cat(
            [source, gaps.reshape(*source.shape[:-1], self.n_rays).to(source.dtype)], dim=-1))
        return next_tensordict

    forward = _call

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
               ) -> TensorDictBase:
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        return appended_spec(observation_spec, self.in_keys[0], self.out_keys[0], self.n_rays)
