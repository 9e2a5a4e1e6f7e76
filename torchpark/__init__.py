"""torchpark: batched autonomous-parking simulation for reinforcement learning in TorchRL."""

from torchpark.actions import PowerActionMap
from torchpark.config import (
    DockingConfig,
    LidarConfig,
    LotConfig,
    ParkingConfig,
    RewardConfig,
    VehicleConfig,
)
from torchpark.curriculum import OccupancyCurriculum, SuccessCurriculum
from torchpark.env import ParkingEnv
from torchpark.features import GoalFrameFeatures
from torchpark.gym_env import ENV_ID, ParkingGymEnv, ParkingVectorEnv, register

register()  # gymnasium.make("torchpark/Parking-v0")

__all__ = [
    "ENV_ID",
    "DockingConfig",
    "GoalFrameFeatures",
    "LidarConfig",
    "LotConfig",
    "OccupancyCurriculum",
    "ParkingConfig",
    "ParkingEnv",
    "ParkingGymEnv",
    "ParkingVectorEnv",
    "PowerActionMap",
    "RewardConfig",
    "SuccessCurriculum",
    "VehicleConfig",
]
