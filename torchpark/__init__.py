"""torchpark: batched autonomous-parking simulation for reinforcement learning in TorchRL.

``ParkingEnv(num_envs)`` is the paper's task; ``torchpark.sim`` its simulator as pure tensor
functions; ``torchpark.aids`` the agent-side aids (``ParkingEnv(..., aids=AidsConfig(...))``);
``torchpark.media`` pictures and videos.
"""

from torchpark.aids.actions import GearActionMap, PowerActionMap
from torchpark.aids.config import (
    AidsConfig,
    BrakeConfig,
    DockingConfig,
    NearGoalStarts,
    PlannerConfig,
)
from torchpark.aids.features import ClearanceFeatures, GoalFrameFeatures
from torchpark.aids.success_curriculum import SuccessCurriculum
from torchpark.config import LidarConfig, LotConfig, ParkingConfig, RewardConfig, VehicleConfig
from torchpark.curriculum import OccupancyCurriculum
from torchpark.env import ParkingEnv
from torchpark.gym_env import ENV_ID, ParkingGymEnv, ParkingVectorEnv, register

register()  # gymnasium.make("torchpark/Parking-v0")

__all__ = [
    "ENV_ID",
    "AidsConfig",
    "BrakeConfig",
    "ClearanceFeatures",
    "DockingConfig",
    "GearActionMap",
    "GoalFrameFeatures",
    "LidarConfig",
    "LotConfig",
    "NearGoalStarts",
    "OccupancyCurriculum",
    "ParkingConfig",
    "ParkingEnv",
    "ParkingGymEnv",
    "ParkingVectorEnv",
    "PlannerConfig",
    "PowerActionMap",
    "RewardConfig",
    "SuccessCurriculum",
    "VehicleConfig",
]
