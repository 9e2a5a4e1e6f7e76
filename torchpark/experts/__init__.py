"""Hand-written agents, reference baselines that any learned agent can be set beside. Each
is evaluated like a checkpoint (``python -m trainers.evaluate --expert planner``); they drive a
:class:`~torchpark.env.ParkingEnv` built with their aids; the env never calls them."""

from torchpark.experts.config import ExpertConfig, PlannerConfig
from torchpark.experts.planner import PlannerExpert

__all__ = ["ExpertConfig", "PlannerConfig", "PlannerExpert"]
