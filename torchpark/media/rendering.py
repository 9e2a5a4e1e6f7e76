"""Pictures of lots: one RGB picture per env (walls, slot lines, parked cars, the goal slot, the
ego car with its heading, the LIDAR rays and their hits), and grids of several.

Drawn with Pillow's ``ImageDraw`` (polygons and lines in C). The static part (asphalt, walls,
slot lines) is drawn once per renderer; a picture copies it and draws the per-env part.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from PIL import Image, ImageDraw

from torchpark.config import ParkingConfig
from torchpark.media.overlay import Readout, draw_label, draw_zoom, readout_lines
from torchpark.media.palette import ASPHALT, EGO, GOAL, HEADING, HIT, PARKED, RAY, SLOT_LINE, WALL
from torchpark.memory import check_fits
from torchpark.sim.geometry import box_corners
from torchpark.sim.layout import LotLayout
from torchpark.sim.lidar import ray_angles
from torchpark.sim.observation import NAV_DIM
from torchpark.sim.state import ParkingState
from torchpark.sim.vehicle import vehicle_boxes


class LotRenderer:
    """Draws pictures of one :class:`LotLayout` at ``pixels_per_metre``.

    Args:
        layout: the lot geometry (``ParkingEnv.layout``).
        config: the env's :class:`ParkingConfig` (vehicle size, LIDAR range and rays).
        pixels_per_metre: image scale; the picture spans the lot and its walls.
        lidar: draw the rays and their hits.
    """

    def __init__(self, layout: LotLayout, config: ParkingConfig, pixels_per_metre: float = 10.0,
                 lidar: bool = True) -> None:
        if not pixels_per_metre > 0:
            raise ValueError(f"pixels_per_metre must be > 0, got {pixels_per_metre!r}")
        self.config = config
        self.scale = float(pixels_per_metre)
        self.lidar = lidar
        self.border = config.lot.wall_thickness
        self.world_height = layout.height
        self.num_slots = layout.num_slots
        self.size = (math.ceil((layout.width + 2 * self.border) * self.scale),
                     math.ceil((layout.height + 2 * self.border) * self.scale))
        self._slots = self._pixels(box_corners(layout.slots.cpu()).numpy())  # (S, 4, 2)
        self._cars = self._pixels(box_corners(layout.cars.cpu()).numpy())
        self._angles = ray_angles(config.lidar.n_rays).numpy()
        background = Image.new("RGB", self.size, WALL)
        draw = ImageDraw.Draw(background)
        inner = self._pixels(np.array([[0.0, layout.height], [layout.width, 0.0]]))
        draw.rectangle([tuple(inner[0]), tuple(inner[1])], fill=ASPHALT)
        for slot in self._slots:
            draw.line([tuple(p) for p in (*slot, slot[0])], fill=SLOT_LINE, width=1)
        self._background = background

    @property
    def shape(self) -> tuple[int, int, int]:
        """(H, W, 3) of every picture."""
        return self.size[1], self.size[0], 3

    def _pixels(self, xy: np.ndarray) -> np.ndarray:
        """World metres [..., 2] -> image pixels [..., 2] (x right, y down)."""
        px = (xy[..., 0] + self.border) * self.scale
        py = (self.world_height + self.border - xy[..., 1]) * self.scale
        return np.stack((px, py), axis=-1)

    def picture(self, parked: np.ndarray, goal_slot: int, pose: np.ndarray,
                lidar: np.ndarray | None = None, driver: str | None = None,
                readout: Readout | None = None) -> np.ndarray:
        """One env's picture, (H, W, 3) uint8.

        parked: (S,) bool, slots holding a car; goal_slot: index of the goal slot; pose: (3,)
        rear axle (x m, y m, psi rad); lidar: (n_rays,) distances divided by the range, as in
        the observation (None: no rays); driver: which layer drove the last step (written in
        the top-left corner, e.g. "policy", "docking law", "brake"; None: nothing written);
        readout: the numbers written below it and, near the goal, the zoom in the top-right
        corner (:mod:`torchpark.media.overlay`; None: neither). The goal slot's outline is
        drawn over the car, so it shows when the car covers it.
        """
        image = self._background.copy()
        draw = ImageDraw.Draw(image)
        goal = self._slots[goal_slot]
        draw.polygon([tuple(p) for p in goal], fill=GOAL, outline=SLOT_LINE)
        for car in self._cars[np.flatnonzero(parked)]:
            draw.polygon([tuple(p) for p in car], fill=PARKED)
        ego_box = vehicle_boxes(torch.as_tensor(pose, dtype=torch.float32), self.config.vehicle)
        ego = self._pixels(box_corners(ego_box).numpy())
        draw.polygon([tuple(p) for p in ego], fill=EGO)
        centre = ego_box[:2].numpy().astype(np.float64)
        if self.lidar and lidar is not None:
            max_range = self.config.lidar.max_range
            angles = pose[2] + self._angles
            hits = centre + (np.asarray(lidar, dtype=np.float64)[:, None] * max_range
                             * np.stack((np.cos(angles), np.sin(angles)), axis=-1))
            start, ends = self._pixels(centre), self._pixels(hits)
            for end, distance in zip(ends, lidar, strict=True):
                draw.line([tuple(start), tuple(end)], fill=RAY, width=1)
                if distance < 1.0:
                    r = max(1.5, 0.2 * self.scale)
                    draw.ellipse([end[0] - r, end[1] - r, end[0] + r, end[1] + r], fill=HIT)
        # Heading: a bar across the front of the car and a line from the rear axle to it.
        front = ego[:2]  # box_corners: front-right, front-left first
        draw.line([tuple(front[0]), tuple(front[1])], fill=HEADING,
                  width=max(1, round(self.scale / 4)))
        axle = self._pixels(np.asarray(pose[:2], dtype=np.float64))
        draw.line([tuple(axle), tuple(front.mean(axis=0))], fill=HEADING, width=1)
        draw.polygon([tuple(p) for p in goal], outline=GOAL,
                     width=max(1, round(self.scale / 5)))
        lines = [f"driving: {driver}"] if driver is not None else []
        if readout is not None:
            lines += readout_lines(readout)
            draw_zoom(image, readout, self.config.vehicle, self.scale)
        if lines:
            draw_label(draw, lines)
        return np.asarray(image)


def picture_grid(pictures: list[np.ndarray] | np.ndarray, columns: int | None = None,
                 gap: int = 4) -> np.ndarray:
    """Tile equal-sized (H, W, 3) pictures into one image, row by row, ``gap`` pixels apart
    (white). ``columns`` defaults to ceil(sqrt(len(pictures)))."""
    pictures = list(pictures)
    if not pictures:
        raise ValueError("pictures must hold at least one picture, got none")
    shape = pictures[0].shape
    if any(f.shape != shape for f in pictures):
        shapes = sorted({f.shape for f in pictures})
        raise ValueError(f"pictures must all have one shape, got {shapes}")
    columns = columns or math.ceil(math.sqrt(len(pictures)))
    if columns < 1:
        raise ValueError(f"columns must be >= 1, got {columns}")
    rows = math.ceil(len(pictures) / columns)
    h, w = shape[:2]
    grid = np.full((rows * h + (rows - 1) * gap, columns * w + (columns - 1) * gap, 3), 255,
                   dtype=np.uint8)
    for i, f in enumerate(pictures):
        r, c = divmod(i, columns)
        grid[r * (h + gap): r * (h + gap) + h, c * (w + gap): c * (w + gap) + w] = f
    return grid


def picture_envs(renderer: LotRenderer, state: ParkingState, observation: torch.Tensor,
                 rows: list[int], columns: int | None = None,
                 drivers: list[str] | None = None, readouts: Sequence[Readout] | None = None
                 ) -> np.ndarray:
    """Pictures of the lots of ``rows`` of a batched state (``observation`` (N, D): the
    LIDAR is drawn from it; ``drivers``: each row's driving layer, ``readouts`` its numbers,
    written on its picture): one (H, W, 3) uint8 picture for one row, else a grid. A grid
    larger than the host's free memory is refused before it is drawn."""
    if readouts is not None and len(readouts) != len(rows):
        raise ValueError(f"readouts must hold one readout per index ({len(rows)}), "
                         f"got {len(readouts)}")
    width, height = renderer.size
    check_fits(2 * len(rows) * width * height * 3,  # the pictures and their grid
               f"render_grid of {len(rows)} pictures", torch.device("cpu"))
    index = torch.tensor(rows, device=state.pose.device)
    s = renderer.num_slots
    parked = (state.present[index, :s] > 0.5).cpu().numpy()
    goal = state.goal_slot[index].cpu().numpy()
    pose = state.pose[index].cpu().numpy()
    lidar = observation[index, NAV_DIM:].cpu().numpy()
    labels: list[str | None] = list(drivers) if drivers is not None else [None] * len(rows)
    numbers: list[Readout | None] = (list(readouts) if readouts is not None
                                     else [None] * len(rows))
    pictures = [renderer.picture(*row)
                for row in zip(parked, goal, pose, lidar, labels, numbers, strict=True)]
    return pictures[0] if len(pictures) == 1 else picture_grid(pictures, columns)
