"""A window for Gymnasium's ``render_mode="human"``, through pygame (``pip install
torchpark[human]``), as Gymnasium's own environments draw theirs: each frame shown as it is
made, at the env's ``render_fps``."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.error import DependencyNotInstalled

EXTRA = "pip install 'torchpark[human]' (or pip install pygame)"


class Window:
    """Shows RGB frames (H, W, 3) uint8 in one pygame window, opened at the first frame and
    paced to ``fps`` frames per second. pygame is imported here: without it, a
    ``DependencyNotInstalled`` naming the extra."""

    def __init__(self, fps: float, title: str = "torchpark") -> None:
        try:
            import pygame
        except ImportError as err:
            raise DependencyNotInstalled(f'render_mode="human" opens a window with pygame, '
                                         f"which is not installed: {EXTRA}") from err
        self._pygame, self.fps, self.title = pygame, fps, title
        self._screen: Any = None  # pygame's display surface and clock, once shown
        self._clock: Any = None

    def show(self, frame: np.ndarray) -> None:
        """Draw ``frame`` in the window (opened at the frame's size), then wait out the
        frame's share of a second."""
        pygame = self._pygame
        if self._screen is None:
            pygame.display.init()  # the display only: no sound device is asked for
            pygame.display.set_caption(self.title)
            self._screen = pygame.display.set_mode((frame.shape[1], frame.shape[0]))
            self._clock = pygame.time.Clock()
        surface = pygame.surfarray.make_surface(np.ascontiguousarray(frame.swapaxes(0, 1)))
        self._screen.blit(surface, (0, 0))
        pygame.event.pump()  # the window stays responsive
        pygame.display.flip()
        self._clock.tick(self.fps)

    def close(self) -> None:
        """Close the window (a later frame opens a new one)."""
        if self._screen is not None:
            self._pygame.display.quit()
            self._screen = None
