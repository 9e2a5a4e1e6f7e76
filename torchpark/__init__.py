"""torchpark: batched autonomous-parking simulation for reinforcement learning in TorchRL."""

from torchpark.config import (
    LidarConfig,
    LotConfig,
    ParkingConfig,
    RewardConfig,
    VehicleConfig,
)
from torchpark.env import ParkingEnv

__all__ = [
    "LidarConfig",
    "LotConfig",
    "ParkingConfig",
    "ParkingEnv",
    "RewardConfig",
    "VehicleConfig",
]
