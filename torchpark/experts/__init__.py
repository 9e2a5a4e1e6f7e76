"""Hand-written agents, reference baselines that any learned agent can be set beside. Each
is evaluated like a checkpoint (``python -m trainers.evaluate --expert planner`` or
``--expert teacher``): :class:`PlannerExpert` drives a :class:`~torchpark.env.ParkingEnv`
built with its aids, :class:`Teacher` (the distiller's) a paper's env, composing its aids
itself; the env never calls them."""

from torchpark.experts.config import ExpertConfig, PlannerConfig, TeacherConfig
from torchpark.experts.planner import PlannerExpert
from torchpark.experts.teacher import Teacher

__all__ = ["ExpertConfig", "PlannerConfig", "PlannerExpert", "Teacher", "TeacherConfig"]
