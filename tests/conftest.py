"""Shared fixtures (the default configuration, its lot layout, the device under test) and
helpers (placing the car, stepping, random actions, box polygons).

``python -m pytest --device cuda`` runs the tests that take the ``device`` fixture on that
device (the rest of the suite runs as usual); the default is the CPU. ``--device-only``
runs only those tests (what a lent GPU has to show, and nothing the CPU already did).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
import torch
from tensordict import TensorDict

from torchpark import (
    AidsConfig,
    BrakeConfig,
    DockingConfig,
    NearGoalStarts,
    ParkingConfig,
    ParkingEnv,
)
from torchpark.sim.layout import build_layout

# ---------------------------------------------------------------- compiled configurations
# Compiling a step costs 20-60 s on two cores; a second env of the same build (N, config,
# aids, reset path) reuses the first one's graphs in the same process at no cost, and a new
# process reads them from inductor's cache in a few seconds. The tests whose subject is the
# compiled step therefore build these and no others (tests/test_env.py, test_reset.py,
# test_curriculum.py, test_ring.py).
COMPILED_N = 64
# Short episodes in a full lot: a 40-step rollout ends episodes by every route; with the
# reset inside the step, blocks are spent every few steps.
BUSY = ParkingConfig(max_steps=7, occupancy=0.9)
# Every aid at once, in a full lot, the collision test along the motion.
ALL_AIDS = (ParkingConfig(occupancy=0.9, collision_substeps=4), AidsConfig(
    action_repeat=3, brake=BrakeConfig(steer_clear=5, penalty=-1.0),
    near_goal_starts=NearGoalStarts(), docking=DockingConfig()))
# (config, aids) of the compiled == eager test, by id: the paper's step; every aid (the
# docking law engages: the test checks) with the collision test along the motion.
COMPILED_BUILDS = {"paper": (BUSY, None), "all-aids": ALL_AIDS}
# The reset inside the step (tests/test_ring.py, test_env.py's captured path).
RING_BUILD = {"config": BUSY, "reset_in_step": True, "blocks_ahead": 3}
# The tests that compile these builds with inductor share one pytest-xdist worker
# (``@pytest.mark.xdist_group(COMPILED_GROUP)``), so that each build compiles once a run.
COMPILED_GROUP = "compiled_builds"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--device", default="cpu",
                     help="torch device for the tests that take one, e.g. cuda (default: cpu)")
    parser.addoption("--device-only", action="store_true",
                     help="run only the tests that take the device fixture")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not config.getoption("--device-only"):
        return
    keep, drop = [], []
    for item in items:
        (keep if "device" in getattr(item, "fixturenames", ()) else drop).append(item)
    config.hook.pytest_deselected(items=drop)
    items[:] = keep


@pytest.fixture(scope="session")
def device(request: pytest.FixtureRequest) -> torch.device:
    name = request.config.getoption("--device")
    try:
        dev = torch.device(name)
    except RuntimeError as err:
        raise pytest.UsageError(f"--device must be a torch device, got {name!r}") from err
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise pytest.UsageError("--device cuda: torch sees no CUDA device")
    return dev


@pytest.fixture(scope="session")
def config() -> ParkingConfig:
    return ParkingConfig()


@pytest.fixture(scope="session")
def layout(config):
    return build_layout(config.lot, config.vehicle)


# ---------------------------------------------------------------- shared helpers
# Imported by the test modules (``from tests.conftest import place``).


def place(env: ParkingEnv, pose: torch.Tensor, rows: torch.Tensor | slice = slice(None)
          ) -> TensorDict:
    """Move the rear axle of ``rows`` to ``pose`` through the env's public ``set_state``
    (the rest of the state as it is); returns what it observes."""
    new = env.state.pose.clone()
    new[rows] = pose
    return env.set_state(env.state._replace(pose=new))


def act(env: ParkingEnv, action) -> TensorDict:
    """One step of every env with ``action`` broadcast to (N, 2); returns ``["next"]``."""
    action = torch.as_tensor(action, dtype=torch.float32, device=env.device)
    return env.step(TensorDict({"action": action.expand(env.num_envs, 2)},
                               batch_size=env.batch_size, device=env.device))["next"]


def random_actions(n: int, steps: int, seed: int) -> torch.Tensor:
    """(steps, n, 2) actions uniform over the paper's bounds, from their own generator."""
    gen = torch.Generator().manual_seed(seed)
    return (torch.rand(steps, n, 2, generator=gen) * 2 - 1) * torch.tensor([5.0, 0.785])


def polygon(box) -> shapely.Polygon:
    """A box [5] = (cx, cy, heading, half_length, half_width) as a shapely polygon, from its
    own trigonometry in float64 (an oracle independent of torchpark.sim.geometry)."""
    cx, cy, h, hl, hw = (float(v) for v in box)
    c, s = math.cos(h), math.sin(h)
    pts = [(cx + a * hl * c - b * hw * s, cy + a * hl * s + b * hw * c)
           for a, b in ((1, -1), (1, 1), (-1, 1), (-1, -1))]
    return shapely.Polygon(pts)


def polygons(boxes: np.ndarray) -> np.ndarray:
    """Boxes (B, 5) as shapely polygons (B,): :func:`polygon`'s corners, array at a time."""
    cx, cy, h, hl, hw = (boxes[:, k, None].astype(np.float64) for k in range(5))
    c, s = np.cos(h), np.sin(h)
    a, b = np.array([1, 1, -1, -1]), np.array([-1, 1, 1, -1])
    return shapely.polygons(np.stack((cx + a * hl * c - b * hw * s,
                                      cy + a * hl * s + b * hw * c), axis=-1))
