"""torchpark: batched autonomous-parking simulation for reinforcement learning in TorchRL.

``ParkingEnv(num_envs)`` is the paper's task; ``torchpark.sim`` its simulator as pure tensor
functions; ``torchpark.aids`` the agent-side layers composed into the step
(``ParkingEnv(..., aids=AidsConfig(...))``); ``torchpark.transforms`` the policy-side TorchRL
transforms; ``torchpark.experts`` the hand-written expert; ``torchpark.media`` pictures and
videos.
"""

from torchpark.aids.config import (
    AidsConfig,
    BrakeConfig,
    DockingConfig,
    NearGoalStarts,
)
from torchpark.config import LidarConfig, LotConfig, ParkingConfig, RewardConfig, VehicleConfig
from torchpark.curriculum import OccupancyCurriculum
from torchpark.env import ParkingEnv
from torchpark.gym_env import ENV_ID, ParkingGymEnv, ParkingVectorEnv, register
from torchpark.transforms.actions import GearActionMap, PowerActionMap
from torchpark.transforms.features import (
    ClearanceFeatures,
    EpisodeFeature,
    GearTravelFeatures,
    GoalFrameFeatures,
    ScanMemory,
    SlotGaps,
)

register()  # gymnasium.make("torchpark/Parking-v0")

__all__ = [
    "ENV_ID",
    "AidsConfig",
    "BrakeConfig",
    "ClearanceFeatures",
    "DockingConfig",
    "EpisodeFeature",
    "GearActionMap",
    "GearTravelFeatures",
    "GoalFrameFeatures",
    "LidarConfig",
    "LotConfig",
    "NearGoalStarts",
    "OccupancyCurriculum",
    "ParkingConfig",
    "ParkingEnv",
    "ParkingGymEnv",
    "ParkingVectorEnv",
    "PowerActionMap",
    "RewardConfig",
    "ScanMemory",
    "SlotGaps",
    "VehicleConfig",
]
