"""Shared fixtures: the default configuration and its lot layout."""

from __future__ import annotations

import pytest

from torchpark import ParkingConfig
from torchpark.lot import build_layout


@pytest.fixture(scope="session")
def config() -> ParkingConfig:
    return ParkingConfig()


@pytest.fixture(scope="session")
def layout(config):
    return build_layout(config.lot, config.vehicle)
