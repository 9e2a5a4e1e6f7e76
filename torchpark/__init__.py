"""torchpark: batched autonomous-parking simulation for reinforcement learning in TorchRL."""

from torchpark.config import (
    LidarConfig,
    LotConfig,
    ParkingConfig,
    RewardConfig,
    VehicleConfig,
)
from torchpark.curriculum import OccupancyCurriculum
from torchpark.env import ParkingEnv

__all__ = [
    "LidarConfig",
    "LotConfig",
    "OccupancyCurriculum",
    "ParkingConfig",
    "ParkingEnv",
    "RewardConfig",
    "VehicleConfig",
]
