"""The numbers a picture can carry (highway-env's on-screen readout): the step, the speed, the
steering, the parking cost C against the success threshold, the outcome, and the car's pose
error in the goal's frame, written in the top-left corner; and near the goal a zoom, drawn
at a scale where a millimetre shows, of the rear axle against the goal pose.

:class:`Readout` holds the numbers (:func:`read_row` reads them from a batched state and a
step's output, for ``ParkingEnv.readout``); :func:`readout_lines` writes them;
:func:`draw_zoom` draws the zoom. The pictures of :mod:`torchpark.media.rendering` draw both
when given a readout.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
from PIL import Image, ImageDraw
from tensordict import TensorDictBase

from torchpark.config import VehicleConfig
from torchpark.media.palette import ASPHALT, EGO, GOAL, LABEL, TEXT
from torchpark.sim.geometry import box_corners
from torchpark.sim.state import ParkingState
from torchpark.sim.vehicle import vehicle_boxes

# The zoom shows when the rear axle is within ZOOM_RADIUS m of the goal's, in a square inset of
# ZOOM_PIXELS px whose scale puts the axle about a third of the way to its edge (at least the
# picture's own scale, at most MAX_ZOOM px/m: 1 mm is 20 px there).
ZOOM_RADIUS = 1.5
ZOOM_PIXELS = 128
MAX_ZOOM = 20_000.0


class Readout(NamedTuple):
    """One env's numbers for the overlay.

    step: steps of dt taken this episode; speed: m/s; steer: the action's steering angle
    delta, rad (None before the first step); cost: the parking cost C; threshold: the
    success test's threshold on C; success, collision: the last step's outcome; along,
    across: the rear axle minus the goal's, in the goal's frame (along its heading, and to
    its left), m; heading: the car's heading minus the goal's, wrapped to (-pi, pi], rad.
    """

    step: int
    speed: float
    steer: float | None
    cost: float
    threshold: float
    success: bool
    collision: bool
    along: float
    across: float
    heading: float

    @property
    def distance(self) -> float:
        """The rear axle's distance to the goal's, m."""
        return math.hypot(self.along, self.across)


def goal_frame_error(pose: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
    """Rear-axle poses [..., 3] (x m, y m, psi rad) against goal poses [..., 3]: [..., 3] of
    (along m, across m, heading rad), the position error in the goal's frame and the
    heading error wrapped to (-pi, pi]."""
    dx, dy = pose[..., 0] - goal[..., 0], pose[..., 1] - goal[..., 1]
    cos, sin = torch.cos(goal[..., 2]), torch.sin(goal[..., 2])
    dpsi = pose[..., 2] - goal[..., 2]
    heading = torch.atan2(torch.sin(dpsi), torch.cos(dpsi))
    return torch.stack((cos * dx + sin * dy, -sin * dx + cos * dy, heading), dim=-1)


def read_row(state: ParkingState, cost: torch.Tensor, threshold: float, index: int,
             tensordict: TensorDictBase | None = None) -> Readout:
    """Row ``index``'s :class:`Readout` from a batched state and its parking costs ``cost``
    (N,) against ``threshold``; the steering and the outcome from ``tensordict``, what a
    step returned (its ``action`` and ``next``); None: before a step (no steering, no
    outcome)."""
    along, across, heading = goal_frame_error(state.pose[index], state.goal[index]).tolist()
    steer, success, collision = None, False, False
    if tensordict is not None:
        outcome = tensordict.get("next", None)
        if outcome is None or "action" not in tensordict.keys():
            raise ValueError("tensordict must be what ParkingEnv.step returned (with "
                             "'action' and 'next'), got one without them")
        steer = float(tensordict["action"][index, 1])
        success = bool(outcome["success"][index, 0])
        collision = bool(outcome["collision"][index, 0])
    return Readout(step=int(state.steps[index]), speed=float(state.speed[index]), steer=steer,
                   cost=float(cost[index]), threshold=threshold, success=success,
                   collision=collision, along=along, across=across, heading=heading)


def _length(metres: float) -> str:
    """A signed length in mm below 1 m, else in m."""
    return f"{metres * 1e3:+.1f} mm" if abs(metres) < 1.0 else f"{metres:+.2f} m"


def readout_lines(readout: Readout) -> list[str]:
    """The overlay's lines of text (ASCII, for any font; three spaces between fields, as the
    default font's spaces are narrow)."""
    steer = "-" if readout.steer is None else f"{math.degrees(readout.steer):+.1f} deg"
    test = "<" if readout.cost < readout.threshold else ">="
    outcome = "PARKED" if readout.success else "COLLISION" if readout.collision else "driving"
    return [f"step {readout.step}   v {readout.speed:+.2f} m/s   steer {steer}",
            f"C {readout.cost:.3g} {test} {readout.threshold:.3g}   {outcome}",
            f"axle off goal:  along {_length(readout.along)}   across "
            f"{_length(readout.across)}",
            f"heading off goal:  {math.degrees(readout.heading):+.2f} deg"]


def draw_label(draw: ImageDraw.ImageDraw, lines: list[str]) -> None:
    """Write ``lines`` on a white label in the top-left corner."""
    text = "\n".join(lines)
    box = draw.multiline_textbbox((4, 2), text)
    draw.rectangle((box[0] - 2, box[1] - 1, box[2] + 2, box[3] + 1), fill=LABEL)
    draw.multiline_text((4, 2), text, fill=TEXT)


def zoom_scale(distance: float, base: float) -> float:
    """The zoom's px/m for a rear axle ``distance`` m from the goal's: the axle a third of the
    inset from its centre, within [``base``, MAX_ZOOM]."""
    return min(max(ZOOM_PIXELS / 3 / max(distance, 1e-9), base), MAX_ZOOM)


def draw_zoom(image: Image.Image, readout: Readout, vehicle: VehicleConfig, base: float) -> None:
    """Paste into ``image``'s top-right corner a ZOOM_PIXELS square of the goal's frame (its
    heading to the right) at :func:`zoom_scale`: the goal's footprint and rear axle in green,
    the car's in orange (each axle a dot with a heading line), and a scale bar of the
    largest power of ten in metres that fits a quarter of the inset. Nothing where the car is
    farther than ZOOM_RADIUS from the goal."""
    if readout.distance > ZOOM_RADIUS:
        return
    scale = zoom_scale(readout.distance, base)
    half = ZOOM_PIXELS / 2
    inset = Image.new("RGB", (ZOOM_PIXELS, ZOOM_PIXELS), ASPHALT)
    draw = ImageDraw.Draw(inset)

    def pixels(xy: np.ndarray) -> list[tuple[float, float]]:
        return [(half + x * scale, half - y * scale) for x, y in np.reshape(xy, (-1, 2))]

    poses = {GOAL: (0.0, 0.0, 0.0),
             EGO: (readout.along, readout.across, readout.heading)}
    for colour, pose in poses.items():
        corners = box_corners(vehicle_boxes(torch.tensor(pose, dtype=torch.float64), vehicle))
        draw.polygon(pixels(corners.numpy()), outline=colour, width=2)
        (ax, ay), = pixels(np.array(pose[:2]))
        end = (ax + 0.4 * ZOOM_PIXELS * math.cos(pose[2]),
               ay - 0.4 * ZOOM_PIXELS * math.sin(pose[2]))
        draw.line([(ax, ay), end], fill=colour, width=1)
        draw.ellipse([ax - 3, ay - 3, ax + 3, ay + 3], fill=colour)
    bar = 10.0 ** math.floor(math.log10(ZOOM_PIXELS / 4 / scale))  # m
    y = ZOOM_PIXELS - 8
    draw.line([(6, y), (6 + bar * scale, y)], fill=LABEL, width=2)
    draw.text((6, y - 13), f"{bar * 1e3:g} mm" if bar < 1 else f"{bar:g} m", fill=LABEL)
    draw.rectangle([0, 0, ZOOM_PIXELS - 1, ZOOM_PIXELS - 1], outline=LABEL)
    image.paste(inset, (image.width - ZOOM_PIXELS - 4, 4))
