"""Shared fixtures: the default configuration, its lot layout, and the device under test.

``python -m pytest --device cuda`` runs the tests that take the ``device`` fixture on that
device (the rest of the suite runs as usual); the default is the CPU.
"""

from __future__ import annotations

import pytest
import torch

from torchpark import ParkingConfig
from torchpark.lot import build_layout


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--device", default="cpu",
                     help="torch device for the tests that take one, e.g. cuda (default: cpu)")


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
